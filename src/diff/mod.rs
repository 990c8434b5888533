//! Differentiable tooling around the renderer: the losses of the paper's depth-from-defocus
//! objective (Eqn. 7) with their gradients. The renderer's own vector-Jacobian product is
//! [`crate::render::backward`].

pub mod dfd;
pub mod loss;
