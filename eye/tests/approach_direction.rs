//! conventions.md, "Encoders": homing ends with every link moving +, so an approach-dependent effect
//! (hinge_backlash) is in its + state at home; a link whose reading did not change keeps the direction
//! it last moved in. The unit model's direction state is [`MotionHistory`]: these tests read the
//! paragraph sentence by sentence.
use abvs_eye::encoder::COUNTS_PER_REV;
use abvs_eye::unit::MotionHistory;

const COUNT_DEG: f64 = 360.0 / COUNTS_PER_REV as f64;

#[test]
fn home_is_the_plus_state() {
    let mut h = MotionHistory::new();
    assert_eq!(h.update(&[0.0, 0.0, 0.0]), [1.0; 3], "the first reading after homing is in the + state");
    assert_eq!(h.update(&[0.0, 0.0, 0.0]), [1.0; 3], "standing still at home stays +");
}

#[test]
fn an_unchanged_link_keeps_its_last_direction() {
    let mut h = MotionHistory::new();
    h.update(&[0.0, 0.0, 0.0]);
    // Link 0 moves -, link 1 +, link 2 stays.
    assert_eq!(h.update(&[-1.0, 1.0, 0.0]), [-1.0, 1.0, 1.0]);
    // Nobody moves: each keeps what it last did.
    assert_eq!(h.update(&[-1.0, 1.0, 0.0]), [-1.0, 1.0, 1.0]);
    // Less than half a count is no motion (encoder quantisation), a full count is.
    assert_eq!(h.update(&[-1.0 + 0.4 * COUNT_DEG, 1.0, 0.0]), [-1.0, 1.0, 1.0]);
    assert_eq!(h.update(&[-1.0 + 0.4 * COUNT_DEG, 1.0 - COUNT_DEG, 0.0]), [-1.0, -1.0, 1.0]);
}
