//! Evaluation: metrics (and, with the benchmark, synthetic scenes and ground truth).

pub mod groundtruth;
pub mod metrics;
