//! gb-diagnose
