//! The calibration methods, one typed name from the command line to `manifest.json`.
use crate::error::{FkError, Result};
use serde::{Deserialize, Serialize};

/// How a model was calibrated; written as its lowercase name (`"m2"`, `"hybrid"`) in
/// `manifest.json` and taken by that name on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[cfg_attr(feature = "clap", value(rename_all = "lower"))]
pub enum Method {
    /// Hand-eye: the camera mount on the nominal kinematics.
    Mh,
    /// The paper's plain MLP.
    M1,
    /// The paper's shared trunk with rotation and translation branches.
    M2,
    /// M1 fine-tuned on another unit.
    M1f,
    /// M2 fine-tuned on another unit.
    M2f,
    /// M2 fine-tuned into an internal and an external network split by the PSC.
    M4f,
    /// The unit model's static effects fitted, plus a residual network.
    Hybrid,
}

impl Method {
    pub const ALL: [Method; 7] =
        [Method::Mh, Method::M1, Method::M2, Method::M1f, Method::M2f, Method::M4f, Method::Hybrid];

    pub fn parse(s: &str) -> Result<Method> {
        Method::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| FkError::Invalid(format!("unknown method '{s}' (mh, m1, m2, m1f, m2f, m4f, hybrid)")))
    }

    pub fn name(self) -> &'static str {
        match self {
            Method::Mh => "mh",
            Method::M1 => "m1",
            Method::M2 => "m2",
            Method::M1f => "m1f",
            Method::M2f => "m2f",
            Method::M4f => "m4f",
            Method::Hybrid => "hybrid",
        }
    }

    /// Whether the model evaluates a unit model (`unit.toml`), with or without a network.
    pub fn is_physics(self) -> bool {
        matches!(self, Method::Mh | Method::Hybrid)
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Method {
    type Err = FkError;
    fn from_str(s: &str) -> Result<Method> {
        Method::parse(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_through_serde_and_parse() {
        for m in Method::ALL {
            assert_eq!(serde_json::to_string(&m).unwrap(), format!("\"{}\"", m.name()));
            assert_eq!(serde_json::from_str::<Method>(&format!("\"{m}\"")).unwrap(), m);
            assert_eq!(Method::parse(m.name()).unwrap(), m);
        }
        assert!(Method::parse("m3").is_err());
    }
}
