//! Telea (2004) fast-marching inpainting.
