//! A worker's reusable buffers for the stripes it renders ([`Scratch`]): shared by the stripe
//! loop (`stripe`), the physical profile's source scan (`physical`) and the binned disks
//! (`binned`), so it lives beside them rather than in any one of them.

use crate::render::splat::Stripe;

/// A worker's reusable buffers (sized on first use, then recycled from stripe to stripe).
#[derive(Default)]
pub(super) struct Scratch {
    /// Accumulators: `A`, then per side its full pass and `U_ka, …, U_kb` for the stripe's
    /// nodes (see `band::slot`).
    pub(super) accs: Vec<Stripe>,
    /// `q` of the stripe's targets.
    pub(super) q: Vec<f32>,
    /// The stripe's finished raw pixels ([`crate::render::raw::CHANNELS`] each).
    pub(super) raw: Vec<f32>,
    /// One row of `A`, of the front and behind sides (`B`) and of one `U_k` (4 channels per
    /// pixel), and one coarse row.
    pub(super) row_a: Vec<f32>,
    pub(super) row_b: Vec<f32>,
    pub(super) row_h: Vec<f32>,
    pub(super) row_u: Vec<f32>,
    pub(super) tmp: Vec<f32>,
    /// Tap weights per stencil row `-stencil.p..=stencil.p` (first column offset, weights)
    /// of a source with scatter radius `stencil_sigma` (reused while σ repeats: in-focus
    /// regions and planes of constant depth).
    pub(super) stencil_w: Vec<(i64, Vec<f32>)>,
    pub(super) stencil_sigma: f32,
    /// One rim row of a bright source.
    pub(super) rim: Vec<f32>,
    /// Columns of one row's band targets.
    pub(super) band_x: Vec<usize>,
    /// (accumulator, factor) pairs a source scatters into.
    pub(super) dests: Vec<(usize, f32)>,
    /// The medium disks of one row of sources, batched per radius bin.
    pub(super) bins: super::binned::RowBatch,
    /// The templates this worker drew them with (the pool of scratch is per layer).
    pub(super) templates: super::binned::Templates,
    /// The visibility's summed-area table and the stripe's visibilities.
    pub(super) sat: Vec<f64>,
    pub(super) vis: Vec<f32>,
}
