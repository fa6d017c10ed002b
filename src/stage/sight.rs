//! The sight-line flags: how far a sight line goes and how the Earth's
//! curvature and the air's refraction bend it. Every command and stage that
//! casts sight lines (horizons, the viewsheds, the total viewshed, a point's
//! horizon profile) flattens [`SightLines`] into its flags and its recipe
//! table, so the three flags mean, default and are checked the same way
//! everywhere; the sky stage reads them back from the horizons' record.
//!
//! The keys stay flat (`max_distance`, `curvature`, `refraction` beside a
//! stage's own) in recipes and manifest records: serde's `flatten` takes
//! them out of the stage's table, and the stage's `deny_unknown_fields`
//! still refuses what neither takes. The block itself must not deny unknown
//! keys (they are the stage's), nor flatten anything of its own (a nested
//! flatten leaves its keys for the outer check to call unknown).

use terrabake_format::Manifest;

use crate::stage::args::check_positive;
use crate::terrain::held::curvature_for;
use crate::terrain::{check_refraction, DEFAULT_REFRACTION};

/// How far sight lines go and how the Earth bends them.
#[derive(Debug, Clone, Copy, PartialEq, clap::Args, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct SightLines {
    /// Sight lines end this many metres from their post or observer (default: at the DEM's
    /// edge, exact).
    #[arg(long, allow_hyphen_values = true, value_parser = crate::stage::args::parse_positive)]
    pub max_distance: Option<f64>,
    /// Earth curvature, drop d^2 (1 - k) / 2R: on, off (default: on for georeferenced DEMs).
    #[arg(long, value_parser = crate::stage::args::parse_on_off)]
    pub curvature: Option<bool>,
    /// Refraction coefficient k of the curvature drop.
    #[arg(long, default_value_t = DEFAULT_REFRACTION)]
    pub refraction: f64,
}

impl Default for SightLines {
    /// To the DEM's edge; curvature as the DEM's georeferencing says, with
    /// the usual refraction.
    fn default() -> Self {
        Self {
            max_distance: None,
            curvature: None,
            refraction: DEFAULT_REFRACTION,
        }
    }
}

impl SightLines {
    /// Sight lines that end `max_distance` metres out (at the DEM's edge
    /// with `None`), curvature as the DEM's georeferencing says.
    pub fn within(max_distance: Option<f64>) -> Self {
        Self {
            max_distance,
            ..Self::default()
        }
    }

    /// Refuses a distance that is not a positive number of metres and a
    /// refraction that is not finite (what a recipe can say and the flags'
    /// parsers would not let through).
    pub fn check(&self) -> crate::Result<()> {
        check_positive(("max_distance", "max-distance"), self.max_distance)?;
        Ok(check_refraction(self.refraction)?)
    }

    /// The coefficient `c` of the curvature drop `c d^2` on the DEM that
    /// `m` describes: 0 where curvature is off.
    pub fn curvature_coefficient(&self, m: &Manifest) -> f64 {
        curvature_for(m, self.curvature, self.refraction)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stage's table as recipes and records hold it: the block's keys
    /// flat beside the stage's own, typos refused by the stage.
    #[derive(Debug, PartialEq, serde::Serialize, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Stage {
        sectors: usize,
        #[serde(flatten)]
        sight: SightLines,
    }

    #[test]
    fn the_keys_stay_flat_and_typos_are_still_refused() {
        let stage: Stage =
            toml::from_str("sectors = 8\nmax_distance = 300\nrefraction = 0.2").expect("flat keys");
        assert_eq!(stage.sight.max_distance, Some(300.0));
        assert_eq!(stage.sight.curvature, None);
        assert_eq!(stage.sight.refraction, 0.2);
        let record = serde_json::to_value(&stage).unwrap();
        assert_eq!(
            record,
            serde_json::json!({"sectors": 8, "max_distance": 300.0, "curvature": null, "refraction": 0.2})
        );
        assert_eq!(serde_json::from_value::<Stage>(record).unwrap(), stage);
        let typo = toml::from_str::<Stage>("sectors = 8\nmax_distanc = 300").unwrap_err();
        assert!(
            typo.to_string().contains("unknown field `max_distanc`"),
            "{typo}"
        );
        let defaults: Stage = toml::from_str("sectors = 8").unwrap();
        assert_eq!(defaults.sight, SightLines::default());
    }

    #[test]
    fn check_refuses_what_a_recipe_can_say() {
        assert!(SightLines::default().check().is_ok());
        for d in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let e = SightLines::within(Some(d)).check().unwrap_err().to_string();
            assert!(
                e.contains("max_distance") && e.contains("positive number"),
                "{e}"
            );
        }
        let s = SightLines {
            refraction: f64::NAN,
            ..SightLines::default()
        };
        assert!(s.check().unwrap_err().to_string().contains("refraction"));
    }
}
