//! Proves: the coated-board heat model behaves like a real emissivity board after a
//! temperature step — the coated-minus-uncoated temperature contrast starts at zero, rises,
//! peaks within minutes and decays; conduction rounds the step at square edges; the heated
//! case has the opposite polarity, physically and as the camera sees it.
//! Does not prove the absolute time constants match a particular physical board (they follow
//! from the documented plate parameters, not from a measurement).
#![allow(clippy::unwrap_used)]

use s3tir_firmware_sim::board::{BoardSpec, BoardThermal};
use s3tir_firmware_sim::physics::Radiometry;

/// Contrast every 10 s over 40 min.
fn contrast_series(mut b: BoardThermal, r: &Radiometry) -> (Vec<f64>, Vec<f64>) {
    let (mut phys, mut app) = (
        vec![b.physical_contrast_k()],
        vec![b.apparent_contrast_k(r)],
    );
    for _ in 0..240 {
        b.advance(10.0);
        phys.push(b.physical_contrast_k());
        app.push(b.apparent_contrast_k(r));
    }
    (phys, app)
}

#[test]
fn cooled_board_contrast_rises_peaks_within_minutes_and_decays() {
    let r = Radiometry::new();
    let (phys, app) = contrast_series(BoardThermal::cooled(BoardSpec::default()), &r);
    assert!(
        phys[0].abs() < 1e-9,
        "no contrast in equilibrium, got {}",
        phys[0]
    );
    let (peak_i, peak) = phys
        .iter()
        .enumerate()
        .fold((0, f64::MIN), |a, (i, &v)| if v > a.1 { (i, v) } else { a });
    let peak_s = peak_i as f64 * 10.0;
    eprintln!(
        "physical contrast peak {peak:.3} K at {peak_s} s; apparent at 0/5/40 min: {:.2} {:.2} {:.2} K",
        app[0], app[30], app[240]
    );
    assert!(
        peak > 0.5,
        "coated squares must lag (stay warmer) by > 0.5 K at the peak, got {peak:.3} K"
    );
    assert!(
        (60.0..=900.0).contains(&peak_s),
        "peak after 1–15 min expected, at {peak_s} s"
    );
    assert!(
        phys[10] > 0.0 && phys[10] < peak,
        "rising at 100 s: {} vs peak {peak}",
        phys[10]
    );
    let end = *phys.last().unwrap();
    assert!(
        end < 0.3 * peak,
        "contrast must decay to < 30 % of the peak by 40 min, got {end:.3} of {peak:.3}"
    );
    // The camera sees coated squares darker (they emit less and reflect the cold surroundings).
    assert!(
        app[30] < -1.0,
        "apparent contrast after 5 min: {:.2} K, want < -1 K",
        app[30]
    );
    assert!(
        app.last().unwrap().abs() < app[30].abs(),
        "apparent contrast decays"
    );
}

#[test]
fn heated_board_has_the_opposite_polarity() {
    let r = Radiometry::new();
    let (cphys, capp) = contrast_series(BoardThermal::cooled(BoardSpec::default()), &r);
    let (hphys, happ) = contrast_series(BoardThermal::heated(BoardSpec::default()), &r);
    for i in [12, 30, 60] {
        assert!(
            cphys[i] > 0.0 && hphys[i] < 0.0,
            "physical contrast at {} s: cooled {:.3}, heated {:.3}: signs must differ",
            i * 10,
            cphys[i],
            hphys[i]
        );
        assert!(
            capp[i] < 0.0 && happ[i] > 0.0,
            "apparent contrast at {} s: cooled {:.3}, heated {:.3}: signs must differ",
            i * 10,
            capp[i],
            happ[i]
        );
    }
    let hmin = hphys.iter().cloned().fold(f64::MAX, f64::min);
    assert!(hmin < -0.5, "heated contrast magnitude > 0.5 K, got {hmin}");
    assert!(
        hphys.last().unwrap().abs() < 0.3 * hmin.abs(),
        "heated contrast decays too"
    );
}

#[test]
fn lateral_conduction_rounds_the_step_at_square_edges() {
    let board = BoardSpec::default();
    let mut b = BoardThermal::cooled(board);
    b.advance(300.0);
    let s = board.square_m;
    // Across the edge between square (0,0) (coated: i+j even) and square (1,0) (uncoated),
    // at y = 0.5 s: the temperature must change smoothly, not in one step.
    let profile: Vec<f64> = (0..=20)
        .map(|k| b.temperature_at(0.5 * s + s * k as f64 / 20.0, 0.5 * s))
        .collect();
    let total = profile[0] - profile[20];
    assert!(
        total > 0.3,
        "coated centre warmer than uncoated centre, diff {total}"
    );
    let max_step = profile
        .windows(2)
        .map(|w| (w[0] - w[1]).abs())
        .fold(0.0, f64::max);
    assert!(
        max_step < 0.5 * total,
        "largest step {max_step} of total {total}: the edge must be blurred"
    );
    assert!(
        profile.windows(2).all(|w| w[0] >= w[1] - 1e-3),
        "monotone across the edge (to 1 mK): {profile:?}"
    );
}
