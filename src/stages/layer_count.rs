//! How many layers the pipeline builds ([`LayerCount`]: `auto` or a count), as the
//! configuration and the command line spell it; read by the segmentation's options and used by
//! the background's slicing ([`super::slices`]).

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};

/// The most layers `--layers auto` builds: the foreground and three background slices.
pub const MAX_AUTO_LAYERS: usize = 4;

/// The most layers a count may ask for (each layer costs a fill and 20 bytes per pixel).
pub const MAX_LAYERS: usize = 8;

/// How many layers the pipeline builds when the scene has a foreground.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LayerCount {
    /// The foreground, then one background slice per valley of the background's disparity
    /// histogram between populations at least `[segment] layer_gap` apart (at most
    /// [`MAX_AUTO_LAYERS`] layers).
    Auto,
    /// Exactly this many (1 ..= [`MAX_LAYERS`]) where the depth allows it: 1 renders the scene
    /// as one layer, 2 is the foreground over the inpainted background, more cut the background
    /// at multi-level Otsu thresholds of its disparity.
    Fixed(usize),
}

impl Default for LayerCount {
    fn default() -> Self {
        LayerCount::Fixed(2)
    }
}

impl LayerCount {
    /// Parses `auto` or a count (the command line's and the configuration's spelling).
    pub fn parse(s: &str) -> std::result::Result<Self, String> {
        let s = s.trim();
        if s.eq_ignore_ascii_case("auto") {
            return Ok(LayerCount::Auto);
        }
        match s.parse::<usize>() {
            Ok(n) if (1..=MAX_LAYERS).contains(&n) => Ok(LayerCount::Fixed(n)),
            _ => Err(format!("expected \"auto\" or a layer count 1..={MAX_LAYERS}, got '{s}'")),
        }
    }

    /// Checks a count read from a configuration (`key` names it in the message).
    pub fn check(self, key: &str) -> Result<()> {
        match self {
            LayerCount::Fixed(n) if !(1..=MAX_LAYERS).contains(&n) => {
                Err(Error::usage(format!("{key} must be \"auto\" or a count 1..={MAX_LAYERS}, got {n}")))
            }
            _ => Ok(()),
        }
    }

    /// The most layers this setting can produce.
    pub fn most(self) -> usize {
        match self {
            LayerCount::Auto => MAX_AUTO_LAYERS,
            LayerCount::Fixed(n) => n,
        }
    }
}

impl std::fmt::Display for LayerCount {
    /// `auto` or the count, as the configuration spells it.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LayerCount::Auto => f.write_str("auto"),
            LayerCount::Fixed(n) => write!(f, "{n}"),
        }
    }
}

impl Serialize for LayerCount {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        match self {
            LayerCount::Auto => s.serialize_str("auto"),
            LayerCount::Fixed(n) => s.serialize_u64(*n as u64),
        }
    }
}

impl<'de> Deserialize<'de> for LayerCount {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        use serde::de::Unexpected;
        // A visitor, not an untagged enum: a wrong value (-1, 2.5, true) is named with what is
        // expected instead of "did not match any variant".
        struct Count;
        impl serde::de::Visitor<'_> for Count {
            type Value = LayerCount;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                write!(f, "\"auto\" or a layer count 1..={MAX_LAYERS}")
            }
            fn visit_u64<E: serde::de::Error>(self, n: u64) -> std::result::Result<LayerCount, E> {
                match usize::try_from(n) {
                    Ok(n) if (1..=MAX_LAYERS).contains(&n) => Ok(LayerCount::Fixed(n)),
                    _ => Err(E::invalid_value(Unexpected::Unsigned(n), &self)),
                }
            }
            fn visit_i64<E: serde::de::Error>(self, n: i64) -> std::result::Result<LayerCount, E> {
                u64::try_from(n).map_err(|_| E::invalid_value(Unexpected::Signed(n), &self)).and_then(|n| self.visit_u64(n))
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> std::result::Result<LayerCount, E> {
                Err(E::invalid_value(Unexpected::Float(v), &self))
            }
            fn visit_str<E: serde::de::Error>(self, s: &str) -> std::result::Result<LayerCount, E> {
                LayerCount::parse(s).map_err(E::custom)
            }
        }
        d.deserialize_any(Count)
    }
}
