//! gb-smc
