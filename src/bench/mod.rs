//! Evaluation: metrics (and, with the benchmark, synthetic scenes and ground truth).

pub mod gather;
pub mod groundtruth;
pub mod metrics;
pub mod plot;
pub mod report;
pub mod run;
pub mod scenes;
pub mod stress;
pub mod trace;
