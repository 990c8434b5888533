//! The integration tests, one binary: a module per file of `tests/` (`cargo test --test suite
//! aperture::` runs one file's). One binary compiles and links the library's generic code once;
//! 27 binaries took ~6.7 of the test build's minutes on 2 cores.

mod common;

mod aperture;
mod backward;
mod batch;
mod bench_cli;
mod cli;
mod dfd_acceptance;
mod dfd_bench;
mod dfd_cli;
mod embedded_depth;
mod fast_kernel;
mod fuzz_regressions;
mod golden;
mod groundtruth;
mod heif;
mod highlights_cli;
mod invariants;
mod io_formats;
mod light_recovery_cli;
mod matting_pymatting;
mod onnx_cli;
mod onnx_stages;
mod report_json;
mod span_tape;
mod stability;
mod telea_opencv;
mod trace;
mod view;
