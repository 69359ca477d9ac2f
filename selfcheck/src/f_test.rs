//! The F distribution's upper tail, for comparing nested least-squares fits (the eye test of
//! [`crate::eye_fit`]): the regularised incomplete beta function by its continued fraction (Lentz).

/// P(F > f) for an F distribution with `d1`, `d2` degrees of freedom (1 for f <= 0; NaN for d1 or d2 <= 0).
pub fn f_upper_tail(f: f64, d1: f64, d2: f64) -> f64 {
    if !(d1 > 0.0 && d2 > 0.0) || f.is_nan() {
        return f64::NAN;
    }
    if f <= 0.0 {
        return 1.0;
    }
    // P(F > f) = I_x(d2 / 2, d1 / 2) with x = d2 / (d2 + d1 f)
    incomplete_beta(d2 / (d2 + d1 * f), 0.5 * d2, 0.5 * d1)
}

/// The regularised incomplete beta function I_x(a, b), x in [0, 1].
fn incomplete_beta(x: f64, a: f64, b: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x >= 1.0 {
        return 1.0;
    }
    let front = (ln_gamma(a + b) - ln_gamma(a) - ln_gamma(b) + a * x.ln() + b * (1.0 - x).ln()).exp();
    // the continued fraction converges fast for x < (a + 1) / (a + b + 2); use the symmetry otherwise
    if x < (a + 1.0) / (a + b + 2.0) {
        front * beta_cf(x, a, b) / a
    } else {
        1.0 - front * beta_cf(1.0 - x, b, a) / b
    }
}

fn beta_cf(x: f64, a: f64, b: f64) -> f64 {
    const TINY: f64 = 1e-300;
    let (qab, qap, qam) = (a + b, a + 1.0, a - 1.0);
    let mut c = 1.0;
    let mut d = 1.0 - qab * x / qap;
    d = if d.abs() < TINY { TINY } else { d };
    d = 1.0 / d;
    let mut h = d;
    for m in 1..300 {
        let m = m as f64;
        let m2 = 2.0 * m;
        for aa in [m * (b - m) * x / ((qam + m2) * (a + m2)), -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))] {
            d = 1.0 + aa * d;
            d = if d.abs() < TINY { TINY } else { d };
            c = 1.0 + aa / c;
            c = if c.abs() < TINY { TINY } else { c };
            d = 1.0 / d;
            h *= d * c;
        }
        if (d * c - 1.0).abs() < 1e-14 {
            break;
        }
    }
    h
}

/// ln Gamma(x) for x > 0 (Lanczos, g = 7, 9 terms; ~1e-15 relative).
fn ln_gamma(x: f64) -> f64 {
    const G: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // reflection
        let pi = std::f64::consts::PI;
        return (pi / (pi * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let t = x + 7.5;
    let s: f64 = G[0] + (1..9).map(|i| G[i] / (x + i as f64)).sum::<f64>();
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + s.ln()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upper_tail_matches_tables() {
        // F(1, d2) = t(d2)^2; F(2, d2) has the closed form (1 + 2 f / d2)^(-d2/2)
        for (f, d2) in [(0.5f64, 10.0f64), (3.0, 20.0), (10.0, 48.0)] {
            let closed: f64 = (1.0 + 2.0 * f / d2).powf(-0.5 * d2);
            assert!((f_upper_tail(f, 2.0, d2) - closed).abs() < 1e-10, "{f} {d2}");
        }
        // F(d1, 2) has the closed form P(F <= f) = (d1 f / (d1 f + 2))^(d1/2)
        for (f, d1) in [(0.3f64, 6.0f64), (4.5, 6.0), (40.0, 12.0)] {
            let closed = 1.0 - (d1 * f / (d1 * f + 2.0)).powf(0.5 * d1);
            assert!((f_upper_tail(f, d1, 2.0) - closed).abs() < 1e-10, "{f} {d1}");
        }
        assert_eq!(f_upper_tail(0.0, 6.0, 48.0), 1.0);
        assert!(f_upper_tail(1e4, 6.0, 48.0) < 1e-12);
        assert!(
            (ln_gamma(5.0) - 24f64.ln()).abs() < 1e-12
                && (ln_gamma(0.5) - std::f64::consts::PI.sqrt().ln()).abs() < 1e-12
        );
    }
}
