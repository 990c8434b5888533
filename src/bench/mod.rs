//! Evaluation: metrics (and, with the benchmark, synthetic scenes and ground truth).

pub mod gather;
pub mod groundtruth;
pub mod metrics;
pub mod scenes;
pub mod stress;
pub mod trace;
