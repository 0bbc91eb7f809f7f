//! `humem eval --replay-variant NAME:key=value,…`: a further replay pass
//! with other settings of `[vpr.verdicts]` or the drift envelope, to
//! compare settings on one's own data in one run.
//!
//! A leaf of its own: the command line parses it before any replay runs,
//! and the replay applies it to the configured parameters.

use humem_core::vpr::params::VprParams;

/// A further pass with other verdict settings (`--replay-variant
/// NAME:key=value,…`, keys of `[vpr.verdicts]`), to compare settings on
/// one's own data in one run.
#[derive(Debug, Clone, PartialEq)]
pub struct Variant {
    /// The pass's name in the table.
    pub name: String,
    /// `key = value` pairs applied over the configured settings.
    pub settings: Vec<(String, String)>,
}

impl std::str::FromStr for Variant {
    type Err = String;

    fn from_str(s: &str) -> Result<Variant, String> {
        let (name, rest) = s
            .split_once(':')
            .ok_or_else(|| format!("{s:?}: expected NAME:key=value,…"))?;
        let settings = rest
            .split(',')
            .filter(|kv| !kv.trim().is_empty())
            .map(|kv| {
                kv.split_once('=')
                    .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
                    .ok_or_else(|| format!("{kv:?}: expected key=value"))
            })
            .collect::<Result<_, _>>()?;
        Ok(Variant {
            name: name.trim().to_string(),
            settings,
        })
    }
}

impl Variant {
    /// `base` with this variant's settings (keys of `[vpr.verdicts]`,
    /// `max_drift_ratio` and `leave_out_rivals_beyond_drift`), checked.
    pub fn apply(&self, base: &VprParams) -> anyhow::Result<VprParams> {
        let mut vpr = base.clone();
        let p = &mut vpr.verdicts;
        for (key, value) in &self.settings {
            let bad = || {
                anyhow::anyhow!(
                    "--replay-variant {}: {key} = {value:?} does not parse",
                    self.name
                )
            };
            match key.as_str() {
                "enabled" => p.enabled = value.parse().map_err(|_| bad())?,
                "radius_steps" => p.radius_steps = value.parse().map_err(|_| bad())?,
                "radius_m" => p.radius_m = Some(value.parse().map_err(|_| bad())?),
                "max_penalty" => p.max_penalty = value.parse().map_err(|_| bad())?,
                "support_gain" => p.support_gain = value.parse().map_err(|_| bad())?,
                "place_graph" => p.place_graph = value.parse().map_err(|_| bad())?,
                "half_life_hours" => p.half_life_hours = value.parse().map_err(|_| bad())?,
                "adapt_threshold" => p.adapt_threshold = value.parse().map_err(|_| bad())?,
                "target_precision" => p.target_precision = value.parse().map_err(|_| bad())?,
                "geometry_miss_rate" => p.geometry_miss_rate = value.parse().map_err(|_| bad())?,
                "min_verdicts" => p.min_verdicts = value.parse().map_err(|_| bad())?,
                "max_threshold_raise" => {
                    p.max_threshold_raise = value.parse().map_err(|_| bad())?
                }
                "max_drift_ratio" => vpr.max_drift_ratio = value.parse().map_err(|_| bad())?,
                "leave_out_rivals_beyond_drift" => {
                    vpr.leave_out_rivals_beyond_drift = value.parse().map_err(|_| bad())?
                }
                other => anyhow::bail!(
                    "--replay-variant {}: no setting {other:?} (max_drift_ratio, leave_out_rivals_beyond_drift, or of [vpr.verdicts]: enabled, radius_steps, radius_m, max_penalty, support_gain, place_graph, half_life_hours, adapt_threshold, target_precision, geometry_miss_rate, min_verdicts, max_threshold_raise)",
                    self.name
                ),
            }
        }
        vpr.validate()
            .map_err(|e| anyhow::anyhow!("--replay-variant {}: {e}", self.name))?;
        Ok(vpr)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A variant sets the drift envelope's bound and rule beside the
    /// verdicts' settings, and a bad value names itself.
    #[test]
    fn a_variant_sets_the_drift_bound_and_verdict_settings() {
        let v: Variant =
            "open:max_drift_ratio=1,max_penalty=0.5,leave_out_rivals_beyond_drift=true"
                .parse()
                .unwrap();
        let p = v.apply(&VprParams::default()).unwrap();
        assert_eq!(p.max_drift_ratio, 1.0);
        assert_eq!(p.verdicts.max_penalty, 0.5);
        assert!(p.leave_out_rivals_beyond_drift);
        let bad: Variant = "bad:max_drift_ratio=0".parse().unwrap();
        let e = bad.apply(&VprParams::default()).unwrap_err().to_string();
        assert!(e.contains("max_drift_ratio"), "{e}");
    }
}
