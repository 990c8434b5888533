//! Evaluation: metrics (and, with the benchmark, synthetic scenes and ground truth); the
//! depth-from-defocus evaluation (`bench --dfd`) in [`dfd_eval`] and [`dfd_report`].

pub mod depth_metrics;
pub mod dfd_eval;
pub mod dfd_report;
pub mod gather;
pub mod groundtruth;
pub mod input_report;
pub mod inputs;
pub mod metrics;
pub mod outline;
pub mod report;
pub mod run;
pub mod scenes;
pub mod stress;
pub mod summary;
pub mod trace;
