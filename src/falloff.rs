//! The falloff `ρ(d)` of obscurance `A(p) = (1/π) ∫_Ω ρ(d(p,ω)) max(n·ω, 0) dω`: how much light
//! an occluder at distance `d` still lets through. Every estimator, the reference and the
//! synthetic ground truth read it from here, so a result and the reference it is scored
//! against use the same function, and `t_max = ∞` means plain ambient occlusion for every
//! falloff that reaches 1 only at `t_max`.

use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::fmt;

/// Shape of `ρ` below `t_max`; `ρ = 1` (no occlusion) at and beyond `t_max` for all of them.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Falloff {
    /// `ρ = x²(3 − 2x)`, `x = d/t_max` (the specification's default).
    #[default]
    Smoothstep,
    /// `ρ = d/t_max`.
    Linear,
    /// `ρ = 1 − e^(−d/λ)` with decay length `λ` in metres (Zhukov's obscurance); it jumps to 1
    /// at `t_max` when `t_max` is finite.
    Exp(f32),
    /// `ρ = 0`: every occluder nearer than `t_max` blocks fully (plain ambient occlusion
    /// limited to `t_max`).
    None,
}

impl Falloff {
    /// Parses `smoothstep`, `linear`, `none` or `exp:λ` (λ a positive number of metres).
    pub fn parse(s: &str) -> Result<Falloff, String> {
        let bad = || format!("falloff must be smoothstep, linear, none or exp:METRES, got '{s}'");
        match s.trim().to_ascii_lowercase().as_str() {
            "smoothstep" => Ok(Falloff::Smoothstep),
            "linear" => Ok(Falloff::Linear),
            "none" => Ok(Falloff::None),
            other => {
                let l = other.strip_prefix("exp:").ok_or_else(bad)?;
                match l.trim().parse::<f32>() {
                    Ok(v) if v > 0.0 && v.is_finite() => Ok(Falloff::Exp(v)),
                    _ => Err(bad()),
                }
            }
        }
    }

    /// Whether this is the default (smoothstep).
    pub fn is_default(&self) -> bool {
        *self == Falloff::Smoothstep
    }

    /// `ρ(d)` for falloff distance `tmax` (`f32::INFINITY` allowed); 1 for `d ≥ tmax`, a miss
    /// (`d = ∞`) or a non-positive `tmax`.
    #[inline]
    pub fn rho(self, d: f32, tmax: f32) -> f32 {
        if !(d < tmax) {
            return 1.0;
        }
        match self {
            Falloff::Smoothstep => {
                let x = (d / tmax).clamp(0.0, 1.0);
                x * x * (3.0 - 2.0 * x)
            }
            Falloff::Linear => (d / tmax).clamp(0.0, 1.0),
            Falloff::Exp(l) => 1.0 - (-d.max(0.0) / l).exp(),
            Falloff::None => 0.0,
        }
    }

    /// Whether `ρ(d) = 0` for every finite `d`, so that anything seen blocks fully and an
    /// estimator may skip weighing distances (plain ambient occlusion: `t_max = ∞`).
    pub fn blocks_fully(self, tmax: f32) -> bool {
        tmax == f32::INFINITY && !matches!(self, Falloff::Exp(_))
    }
}

impl fmt::Display for Falloff {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Falloff::Smoothstep => f.write_str("smoothstep"),
            Falloff::Linear => f.write_str("linear"),
            Falloff::Exp(l) => write!(f, "exp:{l}"),
            Falloff::None => f.write_str("none"),
        }
    }
}

impl Serialize for Falloff {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for Falloff {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        Falloff::parse(&s).map_err(serde::de::Error::custom)
    }
}

/// `t_max` as JSON: a number of metres, or the string `"inf"` (JSON has no infinity).
pub fn serialize_tmax<S: Serializer>(t: &f32, s: S) -> Result<S::Ok, S::Error> {
    if t.is_finite() {
        s.serialize_f32(*t)
    } else {
        s.serialize_str("inf")
    }
}

/// `t_max` read back from JSON: a number, `"inf"`, or `null` (how files before `"inf"` wrote
/// infinity).
pub fn tmax_from_json(v: &serde_json::Value) -> Option<f32> {
    match v {
        serde_json::Value::Number(n) => n.as_f64().map(|x| x as f32),
        serde_json::Value::String(s) if matches!(s.as_str(), "inf" | "infinity" | "Inf") => {
            Some(f32::INFINITY)
        }
        serde_json::Value::Null => Some(f32::INFINITY),
        _ => None,
    }
}

/// `--tmax`: a positive number of metres or `inf`.
pub fn parse_tmax(s: &str, flag: &str) -> Result<f32, String> {
    if matches!(s.trim(), "inf" | "infinity" | "Inf") {
        return Ok(f32::INFINITY);
    }
    match s.trim().parse::<f32>() {
        Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!(
            "--{flag} must be a positive number of metres or 'inf', got '{s}'"
        )),
    }
}

/// `t_max` for messages: metres, or `inf`.
pub fn show_tmax(t: f32) -> String {
    if t.is_finite() {
        format!("{t} m")
    } else {
        "inf".into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_prints_every_falloff() {
        for s in ["smoothstep", "linear", "none", "exp:0.5", "exp:2"] {
            let f = Falloff::parse(s).unwrap();
            assert_eq!(Falloff::parse(&f.to_string()).unwrap(), f, "{s}");
        }
        assert_eq!(Falloff::parse(" Linear ").unwrap(), Falloff::Linear);
        for bad in [
            "", "exp", "exp:", "exp:0", "exp:-1", "exp:inf", "exp:nan", "cubic",
        ] {
            let e = Falloff::parse(bad).unwrap_err();
            assert!(e.contains("falloff must be"), "{bad}: {e}");
        }
    }

    #[test]
    fn rho_hand_values() {
        let s = Falloff::Smoothstep;
        assert_eq!(s.rho(0.0, 0.4), 0.0);
        assert!((s.rho(0.1, 0.4) - 0.15625).abs() < 1e-7);
        assert_eq!(s.rho(0.4, 0.4), 1.0);
        assert_eq!(s.rho(5.0, f32::INFINITY), 0.0);
        assert_eq!(s.rho(f32::INFINITY, f32::INFINITY), 1.0);
        assert!((Falloff::Linear.rho(0.1, 0.4) - 0.25).abs() < 1e-7);
        assert_eq!(Falloff::None.rho(0.39, 0.4), 0.0);
        assert_eq!(Falloff::None.rho(0.4, 0.4), 1.0);
        let e = Falloff::Exp(0.5);
        assert!((e.rho(0.5, f32::INFINITY) - (1.0 - (-1.0f32).exp())).abs() < 1e-6);
        assert_eq!(e.rho(0.0, 1.0), 0.0);
        assert_eq!(e.rho(1.0, 1.0), 1.0);
        for f in [s, Falloff::Linear, Falloff::None, e] {
            for d in [0.0, 0.01, 0.3, 10.0, f32::INFINITY] {
                let r = f.rho(d, 0.4);
                assert!((0.0..=1.0).contains(&r), "{f} {d} {r}");
            }
        }
    }

    #[test]
    fn smoothstep_is_the_specifications_function_bit_for_bit() {
        // The estimators' outputs were fixed with this arithmetic: keep its bits.
        for i in 0..=1000 {
            let (d, t) = (i as f32 * 0.00123, 0.8f32);
            let x = (d / t).clamp(0.0, 1.0);
            assert_eq!(
                Falloff::Smoothstep.rho(d, t).to_bits(),
                (x * x * (3.0 - 2.0 * x)).to_bits()
            );
        }
    }

    #[test]
    fn tmax_round_trips_through_json() {
        #[derive(Serialize)]
        struct T {
            #[serde(serialize_with = "serialize_tmax")]
            t: f32,
        }
        for t in [0.25f32, 3.0, f32::INFINITY] {
            let v = serde_json::to_value(T { t }).unwrap();
            assert_eq!(tmax_from_json(&v["t"]), Some(t));
        }
        assert_eq!(
            serde_json::to_string(&T { t: f32::INFINITY }).unwrap(),
            r#"{"t":"inf"}"#
        );
        assert_eq!(
            tmax_from_json(&serde_json::Value::Null),
            Some(f32::INFINITY)
        );
        assert_eq!(tmax_from_json(&serde_json::json!("x")), None);
    }

    #[test]
    fn full_blocking_is_known() {
        assert!(!Falloff::None.blocks_fully(0.4));
        assert!(Falloff::None.blocks_fully(f32::INFINITY));
        assert!(Falloff::Smoothstep.blocks_fully(f32::INFINITY));
        assert!(!Falloff::Smoothstep.blocks_fully(0.4));
        assert!(!Falloff::Exp(1.0).blocks_fully(f32::INFINITY));
    }
}
