//! greybox
