//! Differentiable tooling around the renderer: the losses of the paper's depth-from-defocus
//! objective (Eqn. 7) with their gradients, depth from defocus ([`dfd`]; its plan [`dfd_plan`] and start
//! [`dfd_start`], its guided upsampling [`dfd_upsample`], the light of an 8-bit photo [`dfd_light`]) and its file-level job ([`dfd_job`], the work of `drbokeh dfd`), and the Gaussian-PSF renderer of its ablation
//! ([`gauss_psf`]). The renderer's own vector-Jacobian product is
//! [`crate::render::backward`].

pub mod dfd;
pub mod dfd_confidence;
pub mod dfd_job;
pub mod dfd_light;
pub mod dfd_options;
pub mod dfd_plan;
pub mod dfd_start;
pub mod dfd_upsample;
pub mod gauss_psf;
pub mod loss;
