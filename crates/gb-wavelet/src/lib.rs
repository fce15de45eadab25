//! gb-wavelet
