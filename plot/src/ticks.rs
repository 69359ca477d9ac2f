//! Tick positions and labels. plotters' default labels print at most 5 decimals and never use
//! scientific notation (small residuals, 1e-6 rad, would all read "0.0"), and its log axis
//! only ticks whole decades (a range inside one decade would get no tick at all).

/// Formatter for ticks of a linear axis over `lo..hi` with at most `n` labels: as many
/// decimals as plotters' tick step (1, 2 or 5 x 10^k) needs, scientific for tiny/huge values.
pub(crate) fn linear(lo: f64, hi: f64, n: usize) -> impl Fn(&f64) -> String {
    let step = nice_step((hi - lo).abs(), n.max(2));
    let step_exp = exponent(step);
    let max_abs = lo.abs().max(hi.abs());
    let sci = !(1e-3..1e5).contains(&max_abs);
    move |&v: &f64| {
        // Snap values that are zero up to floating-point noise, so no "-0.00" or "1e-17".
        if v.abs() < step * 1e-6 {
            return "0".into();
        }
        if sci {
            let digits = (exponent(v) - step_exp).max(0) as usize;
            trim_sci(format!("{v:.digits$e}"))
        } else {
            let decimals = (-step_exp).max(0) as usize;
            format!("{v:.decimals$}")
        }
    }
}

/// Tick positions for a log axis over `lo..hi` (0 < lo < hi): decades if there are at least
/// three, else 1-2-5 per decade, else 1..9 per decade, else (a narrow range) linear ticks.
pub(crate) fn log_key_points(lo: f64, hi: f64) -> Vec<f64> {
    let (k0, k1) = (exponent(lo) - 1, exponent(hi) + 1);
    let within = |mults: &[f64]| -> Vec<f64> {
        (k0..=k1)
            .flat_map(|k| mults.iter().map(move |m| m * 10f64.powi(k)))
            .filter(|v| *v >= lo * (1.0 - 1e-9) && *v <= hi * (1.0 + 1e-9))
            .collect()
    };
    let decades = within(&[1.0]);
    if decades.len() >= 3 {
        // Keep the label count readable on very wide ranges.
        let every = decades.len().div_ceil(10);
        return decades.into_iter().step_by(every).collect();
    }
    for mults in [&[1.0, 2.0, 5.0][..], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]] {
        let v = within(mults);
        if v.len() >= 3 {
            return v;
        }
    }
    let step = nice_step(hi - lo, 6);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last).map(|i| i as f64 * step).collect()
}

/// Label of a log-axis tick: the shortest plain number from 0.001 to 10^5, else scientific.
pub(crate) fn log(v: &f64) -> String {
    let v = *v;
    if v <= 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let exp = exponent(v);
    if (-3..5).contains(&exp) {
        // Six significant digits hide float noise (0.30000000000000004), then trim.
        let decimals = (5 - exp).max(0) as usize;
        let s = format!("{v:.decimals$}");
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    } else {
        trim_sci(format!("{v:.5e}"))
    }
}

/// Decimal exponent of |v|, robust to values like 0.1 stored as 0.09999...
fn exponent(v: f64) -> i32 {
    (v.abs().log10() + 1e-9).floor() as i32
}

/// "1.50e-4" -> "1.5e-4", "1.0e-4" -> "1e-4".
fn trim_sci(s: String) -> String {
    match s.split_once('e') {
        Some((m, e)) if m.contains('.') => {
            format!("{}e{e}", m.trim_end_matches('0').trim_end_matches('.'))
        }
        _ => s,
    }
}

/// Smallest 1, 2 or 5 x 10^k step that puts at most `n` ticks on `span` (as plotters does).
fn nice_step(span: f64, n: usize) -> f64 {
    if !(span > 0.0 && span.is_finite()) {
        return 1.0;
    }
    let mut base = 10f64.powf((span / n as f64).log10().floor() - 1.0);
    loop {
        for m in [1.0, 2.0, 5.0] {
            let s = base * m;
            if ((span / s).floor() as usize) < n {
                return s;
            }
        }
        base *= 10.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linear_labels() {
        let f = linear(-31.5, 31.5, 8);
        assert_eq!(f(&-30.0), "-30");
        assert_eq!(f(&0.0), "0");
        let f = linear(0.0, 0.35, 8);
        assert_eq!(f(&0.05), "0.05");
        let f = linear(-1.1e-4, 1.1e-4, 8);
        assert_eq!(f(&5e-5), "5e-5");
        assert_eq!(f(&1e-4), "1e-4");
        assert_eq!(f(&-1.5e-4), "-1.5e-4");
        assert_eq!(f(&1e-20), "0");
    }

    #[test]
    fn log_labels() {
        assert_eq!(log(&0.1), "0.1");
        assert_eq!(log(&0.001), "0.001");
        assert_eq!(log(&0.3), "0.3");
        assert_eq!(log(&(0.1 + 0.2)), "0.3");
        assert_eq!(log(&1e-5), "1e-5");
        assert_eq!(log(&2e-5), "2e-5");
        assert_eq!(log(&100.0), "100");
        assert_eq!(log(&1e6), "1e6");
    }

    #[test]
    fn log_ticks_fit_the_range() {
        assert_eq!(log_key_points(0.005, 2.0), vec![0.01, 0.1, 1.0]);
        let t = log_key_points(0.015, 0.3);
        assert_eq!(t.len(), 4, "{t:?}"); // 0.02 0.05 0.1 0.2
        assert!(t.iter().all(|v| (0.015..=0.3).contains(v)));
        let t = log_key_points(0.021, 0.029);
        assert!(t.len() >= 3 && t.iter().all(|v| (0.021..=0.029).contains(v)), "{t:?}");
        assert!(log_key_points(1e-30, 1e30).len() <= 10);
    }
}
