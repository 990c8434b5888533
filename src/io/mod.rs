//! Reading and writing images, depth maps, mattes and layers.
