//! The classical stages that turn image + depth (+ matte) into layers.

pub mod inpaint;
