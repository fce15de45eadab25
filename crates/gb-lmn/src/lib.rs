//! gb-lmn
