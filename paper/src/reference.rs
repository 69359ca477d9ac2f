//! The paper's numbers (shared/reference/paper.md), set beside ours in the report and the
//! conclusions.

/// Table II, mean |error|: alpha, beta, gamma (deg), x, y, z (mm).
pub(crate) const PAPER_T2: [(&str, [f64; 6]); 3] = [
    ("M_h", [2.053, 0.443, 2.059, 1.714, 0.960, 1.047]),
    ("M1", [0.138, 0.152, 0.136, 0.412, 0.375, 0.428]),
    ("M2", [0.116, 0.122, 0.115, 0.398, 0.364, 0.405]),
];
/// 99.9th percentiles of |error| for M2 (Table II).
pub(crate) const PAPER_M2_MAX: [f64; 6] = [0.65, 1.01, 0.61, 3.4, 4.5, 2.5];
/// Table III, mean |error| alpha/beta/gamma (deg): M_h, M1 of C0 as is, M1f, M2f, M4f.
pub(crate) const PAPER_T3: [(&str, [[f64; 3]; 5]); 3] = [
    ("C1", [[2.10, 0.60, 1.06], [0.36, 0.43, 0.55], [0.25, 0.25, 0.25], [0.21, 0.23, 0.24], [0.21, 0.21, 0.24]]),
    ("C2", [[2.26, 0.47, 1.96], [0.97, 0.41, 0.26], [0.22, 0.21, 0.22], [0.20, 0.16, 0.21], [0.19, 0.15, 0.20]]),
    ("C3", [[2.12, 0.42, 1.99], [0.53, 0.31, 0.33], [0.22, 0.19, 0.22], [0.19, 0.15, 0.21], [0.18, 0.14, 0.20]]),
];
pub(crate) const PAPER_T3_LABELS: [&str; 5] = ["M_h", "M1 of C0 as is", "M1f", "M2f", "M4f"];
/// Table III, M4f translation mean |error| x, y, z (mm).
pub(crate) const PAPER_T3_M4F_TRANS: [(&str, [f64; 3]); 3] =
    [("C1", [0.42, 0.39, 0.58]), ("C2", [0.28, 0.25, 0.21]), ("C3", [0.25, 0.24, 0.20])];
/// Restricted training, MSE_total (inside, outside, whole test set).
pub(crate) const PAPER_M2_RESTRICTED: [f64; 3] = [0.079, 1.904, 0.528];
pub(crate) const PAPER_M2_FULL: [f64; 3] = [0.088, 0.222, 0.180];

/// Table III row order.
pub(crate) const T3_ORDER: [&str; 7] = ["M_h", "M1 of C0 as is", "M2 of C0 as is", "M1f", "M2f", "M4f", "hybrid"];
