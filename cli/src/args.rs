//! Value parsers of the command line: every number is checked where clap parses it (range,
//! finiteness, sizes against what they would allocate), so no subcommand starts work on a value
//! it cannot use and no arithmetic on a user's value can panic. clap prints a refusal as
//! `invalid value 'X' for '--flag <FLAG>': <our reason>`, naming the flag.
//!
//! Use them for new flags: `#[arg(long, value_parser = args::finite_in(0.0, 10.0))]`.
use std::fmt::Display;
use std::str::FromStr;

/// Largest number of grid poses a command builds in memory (a 0.5 deg grid over the workspace).
pub const MAX_GRID_POSES: f64 = 2.0e6;

/// Longest duration in seconds a flag may ask for (about 31 years: far below `Duration`'s limit).
pub const MAX_SECONDS: f64 = 1.0e9;

fn number(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !v.is_finite() {
        return Err(format!("{s} is not a finite number"));
    }
    Ok(v)
}

/// A finite number in [lo, hi].
pub fn finite_in(lo: f64, hi: f64) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    move |s| {
        let v = number(s)?;
        if !(lo..=hi).contains(&v) {
            return Err(format!("{v} is outside the accepted range [{lo}, {hi}]"));
        }
        Ok(v)
    }
}

/// [`finite_in`] as f32.
pub fn finite_in_f32(lo: f32, hi: f32) -> impl Fn(&str) -> Result<f32, String> + Clone + Send + Sync + 'static {
    let f = finite_in(lo as f64, hi as f64);
    move |s| f(s).map(|v| v as f32)
}

/// A finite number in (0, hi].
pub fn positive_up_to(hi: f64) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    move |s| {
        let v = number(s)?;
        if v <= 0.0 {
            return Err(format!("{v} is not positive: the accepted range is (0, {hi}]"));
        }
        if v > hi {
            return Err(format!("{v} is outside the accepted range (0, {hi}]"));
        }
        Ok(v)
    }
}

/// `positive_up_to` as f32.
pub fn positive_up_to_f32(hi: f32) -> impl Fn(&str) -> Result<f32, String> + Clone + Send + Sync + 'static {
    let f = positive_up_to(hi as f64);
    move |s| f(s).map(|v| v as f32)
}

/// A duration in seconds: positive, finite and representable (at most `MAX_SECONDS`).
pub fn seconds() -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    positive_up_to(MAX_SECONDS)
}

/// An integer count in [lo, hi] (of any integer type); the cap keeps what it sizes allocatable.
pub fn count<T>(lo: T, hi: T) -> impl Fn(&str) -> Result<T, String> + Clone + Send + Sync + 'static
where
    T: FromStr + PartialOrd + Display + Copy + Send + Sync + 'static,
{
    move |s| {
        let v: T = s.trim().parse().map_err(|_| format!("'{s}' is not a whole number in [{lo}, {hi}]"))?;
        if v < lo || v > hi {
            return Err(format!("{v} is outside the accepted range [{lo}, {hi}]"));
        }
        Ok(v)
    }
}

/// "a,b,c": three finite numbers.
pub fn vec3(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s.split(',').map(number).collect::<Result<_, _>>()?;
    v.try_into().map_err(|_| format!("'{s}': expected three comma-separated numbers"))
}

/// "a,b": two finite numbers.
pub fn vec2(s: &str) -> Result<[f64; 2], String> {
    let v: Vec<f64> = s.split(',').map(number).collect::<Result<_, _>>()?;
    v.try_into().map_err(|_| format!("'{s}': expected two comma-separated numbers"))
}

/// A point "x,y,z" in metres to look at: each coordinate within +-100 m, and at least 1 cm from
/// the camera (no direction to look in at its centre).
pub fn point_m(s: &str) -> Result<[f64; 3], String> {
    let p = vec3(s)?;
    if let Some(x) = p.iter().find(|x| x.abs() > 100.0) {
        return Err(format!("coordinate {x} m is outside the accepted range [-100, 100] m"));
    }
    if (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() < 0.01 {
        return Err(format!("{p:?} is less than 1 cm from the camera"));
    }
    Ok(p)
}

/// A pixel "u,v": finite, within +-100000 px (beyond any sensor).
pub fn pixel(s: &str) -> Result<[f64; 2], String> {
    let p = vec2(s)?;
    if let Some(x) = p.iter().find(|x| x.abs() > 1e5) {
        return Err(format!("{x} px is outside the accepted range [-100000, 100000] px"));
    }
    Ok(p)
}

/// A gravity direction "gx,gy,gz": a unit vector to 1e-3, as the simulator and sessions demand
/// (a zero or scaled vector would silently change the modelled sag).
pub fn gravity(s: &str) -> Result<[f64; 3], String> {
    let g = vec3(s)?;
    let n = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
    if (n - 1.0).abs() > 1e-3 {
        return Err(format!("gravity {g:?} has length {n:.4}; expected a unit vector (e.g. 0,1,0)"));
    }
    Ok(g)
}

/// Link angles "t1,t2,t3" (deg): each finite and within +-89 deg of home (at 90 deg an SPM link
/// folds onto its neighbour; no pose of the workspace needs more).
pub fn link_angles(s: &str) -> Result<[f64; 3], String> {
    let t = vec3(s)?;
    if let Some(x) = t.iter().find(|x| x.abs() > 89.0) {
        return Err(format!("link angle {x} deg is outside the accepted range [-89, 89] deg"));
    }
    Ok(t)
}

/// Half-ranges "a,b,g" (deg) of the commanded Fick grid: each in (0, 90].
pub fn half_ranges(s: &str) -> Result<[f64; 3], String> {
    let r = vec3(s)?;
    if let Some(x) = r.iter().find(|x| !(**x > 0.0 && **x <= 90.0)) {
        return Err(format!("half-range {x} deg is outside the accepted range (0, 90] deg"));
    }
    Ok(r)
}

/// Poses of a grid with `step` over the half-ranges `r` (each axis -r..=r), as f64 so that a tiny
/// step cannot overflow the count.
pub fn grid_poses(r: [f64; 3], step: f64) -> f64 {
    r.iter().map(|h| (2.0 * h / step).floor() + 1.0).product()
}

/// Refuses a grid step whose grid would exceed `MAX_GRID_POSES`, naming the flag.
pub fn check_grid(flag: &str, r: [f64; 3], step: f64) -> anyhow::Result<()> {
    let n = grid_poses(r, step);
    if n > MAX_GRID_POSES {
        anyhow::bail!(
            "{flag} {step}: a grid of {n:.3e} poses over +-{r:?} deg; the most accepted is {MAX_GRID_POSES:.0e} \
             (a step of at least {:.3} deg)",
            min_step(r)
        );
    }
    Ok(())
}

/// The smallest step whose grid over `r` stays within `MAX_GRID_POSES` (within 1%).
pub fn min_step(r: [f64; 3]) -> f64 {
    let vol: f64 = r.iter().map(|h| 2.0 * h).product();
    let mut s = (vol / MAX_GRID_POSES).cbrt();
    while grid_poses(r, s) > MAX_GRID_POSES {
        s *= 1.01;
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refusals_name_the_range() {
        let f = finite_in(0.0, 1.0);
        assert_eq!(f("0.5"), Ok(0.5));
        for bad in ["NaN", "inf", "-inf", "1e30", "-1", "x", ""] {
            assert!(f(bad).is_err(), "{bad}");
        }
        assert!(f("2").unwrap_err().contains("[0, 1]"));
        assert!(positive_up_to(1.0)("0").is_err());
        let c = count(1usize, 10);
        assert_eq!(c("10"), Ok(10));
        for bad in ["0", "-1", "NaN", "1e30", "11", "99999999999999999999999"] {
            assert!(c(bad).is_err(), "{bad}");
        }
        assert!(seconds()("1e30").is_err());
    }

    #[test]
    fn vectors() {
        assert_eq!(gravity("0,1,0"), Ok([0.0, 1.0, 0.0]));
        assert!(gravity("0,0,0").is_err());
        assert!(gravity("0,2,0").is_err());
        assert!(gravity("0,NaN,0").is_err());
        assert!(link_angles("0,90,0").is_err());
        assert!(half_ranges("30,0,30").is_err());
        assert!(point_m("0,0,0").is_err() && point_m("0,0,1e30").is_err() && point_m("0.05,-0.03,0.5").is_ok());
        assert!(pixel("1e30,1").is_err() && pixel("320,240").is_ok());
    }

    #[test]
    fn grid_sizes() {
        let r = abvs_eye::WORKSPACE_DEG;
        assert!(check_grid("--step-deg", r, 1.0).is_ok());
        assert!(check_grid("--step-deg", r, 1e-9).unwrap_err().to_string().contains("--step-deg"));
        let s = min_step(r);
        assert!(grid_poses(r, s) <= MAX_GRID_POSES && s < 0.6, "{s}");
    }
}
