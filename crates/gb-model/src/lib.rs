//! gb-model
