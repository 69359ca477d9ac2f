//! The closing note's headline numbers and the paper's conclusions, each checked on our units.
use crate::figures::{CENTRE_DEG, OUTER_DEG};
use crate::summary::{Conclusion, ModelResult, PaperSummary};

pub(crate) fn find<'a>(rows: &'a [ModelResult], unit: &str, label: &str) -> Option<&'a ModelResult> {
    rows.iter().find(|r| r.unit == unit && r.label == label)
}

fn reduction_pct(new: f64, old: f64) -> f64 {
    100.0 * (1.0 - new / old)
}

pub(crate) fn headline(s: &PaperSummary) -> std::collections::BTreeMap<String, f64> {
    let mut h = std::collections::BTreeMap::new();
    let t2 = |l: &str| find(&s.table2, "C0", l);
    if let (Some(mh), Some(m1), Some(m2), Some(hy)) = (t2("M_h"), t2("M1"), t2("M2"), t2("hybrid")) {
        h.insert(
            "m2_vs_m1_rot_reduction_pct".into(),
            reduction_pct(m2.rot_norm_of_means_deg, m1.rot_norm_of_means_deg),
        );
        h.insert(
            "m2_vs_m1_trans_reduction_pct".into(),
            reduction_pct(m2.trans_norm_of_means_mm, m1.trans_norm_of_means_mm),
        );
        h.insert(
            "m2_vs_mh_rot_reduction_pct".into(),
            reduction_pct(m2.rot_norm_of_means_deg, mh.rot_norm_of_means_deg),
        );
        h.insert(
            "m2_vs_mh_trans_reduction_pct".into(),
            reduction_pct(m2.trans_norm_of_means_mm, mh.trans_norm_of_means_mm),
        );
        for (k, r) in [("mh", mh), ("m1", m1), ("m2", m2), ("hybrid", hy)] {
            h.insert(format!("c0_{k}_mse_total"), r.eval.mse_total);
            h.insert(format!("c0_{k}_rot_norm_deg"), r.rot_norm_of_means_deg);
            h.insert(format!("c0_{k}_trans_norm_mm"), r.trans_norm_of_means_mm);
            h.insert(format!("c0_{k}_mpe_px"), r.eval.mpe_px);
        }
        for (r, n) in s.hybrid_few.iter().zip(s.config.hybrid_n.iter().map(|n| n.pow(3))) {
            h.insert(format!("c0_hybrid_{n}_mse_total"), r.eval.mse_total);
            h.insert(format!("c0_hybrid_{n}_rot_norm_deg"), r.rot_norm_of_means_deg);
            h.insert(format!("c0_hybrid_{n}_trans_norm_mm"), r.trans_norm_of_means_mm);
            h.insert(format!("c0_hybrid_{n}_mpe_px"), r.eval.mpe_px);
            h.insert(format!("c0_hybrid_{n}_mse_over_m1_full"), r.eval.mse_total / m1.eval.mse_total);
            h.insert(format!("c0_hybrid_{n}_mse_over_m2_full"), r.eval.mse_total / m2.eval.mse_total);
        }
        let n = s.config.table_n.pow(3);
        for u in &s.config.finetune_units {
            let key = u.to_lowercase();
            if let Some(m4) = find(&s.table3, u, "M4f") {
                h.insert(format!("{key}_m4f_{n}_mse_total"), m4.eval.mse_total);
                h.insert(format!("{key}_m4f_{n}_rot_norm_deg"), m4.rot_norm_of_means_deg);
                h.insert(format!("{key}_m4f_{n}_mpe_px"), m4.eval.mpe_px);
                h.insert(format!("{key}_m4f_{n}_mse_over_c0_m1_full"), m4.eval.mse_total / m1.eval.mse_total);
            }
            if let Some(hf) = find(&s.table3, u, "hybrid") {
                h.insert(format!("{key}_hybrid_{n}_mse_total"), hf.eval.mse_total);
                h.insert(format!("{key}_hybrid_{n}_mpe_px"), hf.eval.mpe_px);
            }
        }
        for p in s.fig7.iter().filter(|p| p.label == "hybrid" && p.n_per_axis == 4) {
            h.insert(format!("{}_hybrid_64_mse_total", p.unit.to_lowercase()), p.mse_total);
        }
    }
    for (key, label, full) in
        [("m2", "M2' (restricted)", "M2 (full range)"), ("hybrid", "hybrid' (restricted)", "hybrid (full range)")]
    {
        let full = s.extrapolation.iter().find(|r| r.label == full);
        if let Some(r) = s.extrapolation.iter().find(|r| r.label == label) {
            h.insert(format!("extrap_{key}_restricted_mse_inside"), r.mse_inside);
            h.insert(format!("extrap_{key}_restricted_mse_outside"), r.mse_outside);
            h.insert(format!("extrap_{key}_restricted_outside_over_inside"), r.outside_over_inside);
            if let Some(f) = full {
                h.insert(format!("extrap_{key}_restricted_outside_over_full_outside"), r.mse_outside / f.mse_outside);
            }
        }
    }
    h
}

fn verdict(all: bool, any: bool) -> String {
    if all {
        "holds".into()
    } else if any {
        "partly holds".into()
    } else {
        "does not hold".into()
    }
}

pub(crate) fn conclusions(s: &PaperSummary) -> Vec<Conclusion> {
    let mut out = vec![];
    let t2 = |l: &str| find(&s.table2, "C0", l);
    let (Some(mh), Some(m1), Some(m2)) = (t2("M_h"), t2("M1"), t2("M2")) else {
        return out;
    };
    let (rr, tr) = (
        reduction_pct(m2.rot_norm_of_means_deg, m1.rot_norm_of_means_deg),
        reduction_pct(m2.trans_norm_of_means_mm, m1.trans_norm_of_means_mm),
    );
    out.push(Conclusion {
        claim: "M2 (rotation and translation branches, 2:1 loss) beats M1".into(),
        paper: "rotation error norm -17 %, translation -3.9 %; MPE 2.66 -> 2.06 px (C0)".into(),
        ours: format!(
            "rotation {:.4} -> {:.4} deg ({:+.1} %), translation {:.4} -> {:.4} mm ({:+.1} %); MSE_total {:.5} -> {:.5}; MPE {:.2} -> {:.2} px",
            m1.rot_norm_of_means_deg, m2.rot_norm_of_means_deg, -rr, m1.trans_norm_of_means_mm, m2.trans_norm_of_means_mm, -tr,
            m1.eval.mse_total, m2.eval.mse_total, m1.eval.mpe_px, m2.eval.mpe_px
        ),
        verdict: verdict(rr > 0.0 && tr > 0.0, rr > 0.0 || tr > 0.0),
    });
    let (rh, th) = (
        reduction_pct(m2.rot_norm_of_means_deg, mh.rot_norm_of_means_deg),
        reduction_pct(m2.trans_norm_of_means_mm, mh.trans_norm_of_means_mm),
    );
    out.push(Conclusion {
        claim: "M2 beats nominal kinematics + hand-eye (M_h) by a wide margin".into(),
        paper: "rotation error norm -93 %, translation -69 %".into(),
        ours: format!(
            "rotation {:.4} -> {:.4} deg ({:+.1} %), translation {:.4} -> {:.4} mm ({:+.1} %) (criterion: both reduced by more than half)",
            mh.rot_norm_of_means_deg, m2.rot_norm_of_means_deg, -rh, mh.trans_norm_of_means_mm, m2.trans_norm_of_means_mm, -th
        ),
        verdict: verdict(rh > 50.0 && th > 50.0, rh > 0.0 && th > 0.0),
    });
    let n = s.config.table_n.pow(3);
    let mut per_unit = vec![];
    let (mut wins, mut units) = (0, 0);
    let (mut as_is_wins, mut as_is_txt) = (0, vec![]);
    for u in &s.config.finetune_units {
        let g = |l: &str| find(&s.table3, u, l);
        if let (Some(m4), Some(m1f), Some(m2f)) = (g("M4f"), g("M1f"), g("M2f")) {
            units += 1;
            let best = m1f.rot_norm_of_means_deg.min(m2f.rot_norm_of_means_deg);
            if m4.rot_norm_of_means_deg < best {
                wins += 1;
            }
            per_unit.push(format!(
                "{u}: rotation M1f {:.4} / M2f {:.4} / M4f {:.4} deg (M4f vs M2f {:+.1} %), MSE_total {:.5} / {:.5} / {:.5}",
                m1f.rot_norm_of_means_deg,
                m2f.rot_norm_of_means_deg,
                m4.rot_norm_of_means_deg,
                -reduction_pct(m4.rot_norm_of_means_deg, m2f.rot_norm_of_means_deg),
                m1f.eval.mse_total,
                m2f.eval.mse_total,
                m4.eval.mse_total
            ));
            if let Some(a) = g("M2 of C0 as is") {
                let ratio = a.eval.mpe_px / m4.eval.mpe_px;
                if ratio >= 2.0 {
                    as_is_wins += 1;
                }
                as_is_txt.push(format!(
                    "{u}: MPE {:.2} px as is vs {:.2} px after M4f ({ratio:.1}x); MSE_total {:.4} vs {:.5}",
                    a.eval.mpe_px, m4.eval.mpe_px, a.eval.mse_total, m4.eval.mse_total
                ));
            }
        }
    }
    if units > 0 {
        out.push(Conclusion {
            claim: format!("With {n} fine-tuning samples M4f beats M1f and M2f"),
            paper: "mean rotation |error| on C1/C2/C3: M4f <= M2f < M1f (Table III)".into(),
            ours: format!("M4f has the lowest rotation error norm on {wins} of {units} units. {}", per_unit.join("; ")),
            verdict: verdict(wins == units, wins > 0),
        });
        out.push(Conclusion {
            claim: "C0's model applied as is to a new unit is much worse than after fine-tuning".into(),
            paper: "C1: MPE 9.61 px with C0's model vs 3.47 px with M4f (343 samples)".into(),
            ours: format!("{} (criterion: at least 2x on every unit)", as_is_txt.join("; ")),
            verdict: verdict(as_is_wins == units, as_is_wins > 0),
        });
    }
    let ex = |l: &str| s.extrapolation.iter().find(|r| r.label == l);
    if let (Some(f), Some(r)) = (ex("M2 (full range)"), ex("M2' (restricted)")) {
        let vs_full = r.mse_outside / f.mse_outside;
        out.push(Conclusion {
            claim: "Training on the restricted range degrades about 10x outside it".into(),
            paper: "M2' MSE_total outside 1.904 vs 0.222 with full training (8.6x), 24x its own inside error (0.079); inside 0.079 vs 0.088".into(),
            ours: format!(
                "M2' outside {:.4} vs {:.4} with full training ({vs_full:.1}x), {:.1}x its inside error ({:.5}); inside {:.5} vs {:.5} (criterion: >= 5x holds, >= 2x partly)",
                r.mse_outside, f.mse_outside, r.outside_over_inside, r.mse_inside, r.mse_inside, f.mse_inside
            ),
            verdict: verdict(vs_full >= 5.0, vs_full >= 2.0),
        });
    }
    if let Some(m) = s.fig8.iter().find(|m| m.unit == "C0" && m.label == "M_h") {
        let ratio = m.outer_mpe_px / m.centre_mpe_px;
        out.push(Conclusion {
            claim: "M_h errors grow from the centre of the workspace outwards".into(),
            paper: "Fig. 8: M_h projection error lowest at the centre, growing outwards".into(),
            ours: format!(
                "M_h MPE {:.2} px in cells with max(|alpha|, |gamma|) <= {CENTRE_DEG} deg, {:.2} px beyond {OUTER_DEG} deg ({ratio:.2}x) (criterion: > 1.25x)",
                m.centre_mpe_px, m.outer_mpe_px
            ),
            verdict: verdict(ratio > 1.25, ratio > 1.0),
        });
    }
    out
}
