//! The layout of a raw layer pixel, what every per-layer kernel produces and the compositor
//! reads: `[ΣR, ΣG, ΣB, W, o]`, the colour sums weighted by `w·O·α`, their total weight `W`
//! and the non-focal visibility `o` (eq. 4). The same channels as the official renderer's
//! per-layer output (see [`super::RawLayer`]).

/// Channels of a raw layer pixel.
pub const CHANNELS: usize = 5;
/// Index of the total weight `W` (the colour sums are at 0, 1, 2).
pub const WEIGHT: usize = 3;
/// Index of the non-focal visibility `o`, in [0, 1].
pub const VISIBILITY: usize = 4;

/// One raw layer pixel.
pub type Pixel = [f32; CHANNELS];
