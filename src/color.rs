//! Transfer functions between encoded pixel values and linear light.

/// How 8/16-bit pixel values relate to linear light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Transfer {
    /// The exact sRGB (IEC 61966-2-1) piecewise curve.
    Srgb,
    /// The official Dr.Bokeh "naive gamma": linear = encoded^g.
    Gamma(f32),
    /// Values are already linear.
    Linear,
}

impl Transfer {
    /// Encoded value in [0, 1] (or beyond, for HDR) to linear light.
    #[inline]
    pub fn decode(self, v: f32) -> f32 {
        match self {
            Transfer::Srgb => srgb_to_linear(v),
            Transfer::Gamma(g) => v.max(0.0).powf(g),
            Transfer::Linear => v,
        }
    }

    /// Linear light to encoded value (not clipped).
    #[inline]
    pub fn encode(self, v: f32) -> f32 {
        match self {
            Transfer::Srgb => linear_to_srgb(v),
            Transfer::Gamma(g) => v.max(0.0).powf(1.0 / g),
            Transfer::Linear => v,
        }
    }
}

/// How a photo's values relate to the light in front of the camera: what the highlights stage
/// (`stages::light_recovery`) must know to tell clipped light from white.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PhotoEncoding {
    /// Linear values as stored (EXR, float TIFF, float NPY): nothing was clipped at white.
    Linear,
    /// Integer samples of `bits` bits (8 or 16: PNG, JPEG, TIFF, uint NPY), decoded to linear
    /// with `transfer`: the largest code decodes to 1.0 and holds all the light above it.
    Integer {
        /// Bits per sample.
        bits: u8,
        /// The curve the samples were decoded with.
        transfer: Transfer,
    },
}

impl PhotoEncoding {
    /// The curve that maps this photo's linear values to the values its file stores (sRGB for
    /// a linear photo: the scale a user's threshold is given in).
    pub fn transfer(self) -> Transfer {
        match self {
            PhotoEncoding::Linear => Transfer::Srgb,
            PhotoEncoding::Integer { transfer, .. } => transfer,
        }
    }
}

/// The sRGB decoding curve (IEC 61966-2-1): encoded value in [0, 1] → linear light.
/// Values above 1 follow the power law; negative values are divided by 12.92.
#[inline]
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 { v / 12.92 } else { ((v + 0.055) / 1.055).powf(2.4) }
}

/// The sRGB encoding curve: linear light → encoded value (1 → 1; negatives → 0). Not
/// clipped above 1.
#[inline]
pub fn linear_to_srgb(v: f32) -> f32 {
    if v <= 0.003_130_8 { v.max(0.0) * 12.92 } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_round_trip() {
        for i in 0..=255 {
            let v = i as f32 / 255.0;
            assert!((linear_to_srgb(srgb_to_linear(v)) - v).abs() < 1e-5, "{v}");
        }
        assert!((srgb_to_linear(0.5) - 0.214_041).abs() < 1e-5);
    }
}
