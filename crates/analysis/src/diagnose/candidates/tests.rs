//! The candidate library's offers and its sweeps' columns against their definitions.

use super::*;
use retrocomp_model::recording::Recording;

fn thermal_lib(rpm: impl Fn(usize) -> f64) -> Vec<String> {
    let n = 400;
    let rec = Recording::from_columns(vec![
        ("t_s".into(), (0..n).map(|i| 15.0 * i as f64).collect()),
        ("rpm".into(), (0..n).map(&rpm).collect()),
        ("ez_um".into(), vec![0.0; n]),
    ])
    .unwrap();
    library(&Context::from_recording(&rec), 'z')
        .iter()
        .map(Candidate::label)
        .collect()
}

#[test]
fn squared_speed_is_a_lag_driver_only_when_rpm_has_several_levels() {
    // On/off at one speed: (rpm/1000)² is a multiple of rpm, no information of its own.
    let one = thermal_lib(|i| if (i / 100) % 2 == 0 { 3000.0 } else { 0.0 });
    assert!(one.contains(&"thermal_lag(rpm)".to_string()), "{one:?}");
    assert!(!one.iter().any(|l| l.contains("krpm^2")), "{one:?}");
    // 0, 1250, 2500 rpm: offered, as a lag only (like rpm).
    let three = thermal_lib(|i| [1250.0, 0.0, 2500.0, 0.0][i / 100]);
    assert!(
        three.contains(&"thermal_lag(krpm^2)".to_string()),
        "{three:?}"
    );
    assert!(
        !three.contains(&"thermal_drift(krpm^2)".to_string()),
        "{three:?}"
    );
}

/// A thermal lag's swept columns (time constants carried side by side, `lag::series_each`)
/// are each the sensor's `lowpass` minus its first reading, bit for bit, on one thread and
/// on three, over a grid that is not a whole number of lane groups; so is each τ's column alone.
#[test]
fn a_lags_swept_columns_are_each_lowpass_minus_the_first_reading_bit_for_bit() {
    let n = 2000;
    // Uneven sample periods (they alternate, as a 1 kHz clock in decimal seconds does).
    let t: Vec<f64> = (0..n)
        .map(|i| 0.7 * i as f64 + [0.0, 0.013, 0.05][i % 3])
        .collect();
    let temp: Vec<f64> = (0..n).map(|i| 20.0 + (i as f64 / 150.0).sin()).collect();
    let rec = Recording::from_columns(vec![
        ("t_s".into(), t.clone()),
        ("T_spindle_C".into(), temp.clone()),
        ("ez_um".into(), vec![0.0; n]),
    ])
    .unwrap();
    let ctx = Context::from_recording(&rec);
    let lag = library(&ctx, 'z')
        .into_iter()
        .find(|c| c.label() == "thermal_lag(T_spindle_C)")
        .expect("a lag candidate");
    assert!(
        lag.grid.len() % retrocomp_model::lag::LANES != 0,
        "{}",
        lag.grid.len()
    );
    let want: Vec<(u64, Vec<u64>)> = lag
        .grid
        .iter()
        .map(|&tau_s| {
            let col = super::super::features::lowpass(&t, &temp, tau_s);
            (
                tau_s.to_bits(),
                col.iter().map(|v| (v - temp[0]).to_bits()).collect(),
            )
        })
        .collect();
    assert_sweep_is(&ctx, &lag, &want);
}

/// A reversal spike's swept columns (one distance-since-reversal column for the grid) are
/// each direction × e^(−s/decay) bit for bit, on one thread and on three.
#[test]
fn a_spikes_swept_columns_share_one_distance_column_bit_for_bit() {
    let n = 1500;
    // Back and forth over 0…40 mm in 0.1 mm steps: a reversal every 400 rows.
    let x: Vec<f64> = (0..n)
        .map(|i| 40.0 - ((i % 800) as f64 * 0.1 - 40.0).abs())
        .collect();
    let rec = Recording::from_columns(vec![
        ("t_s".into(), (0..n).map(|i| i as f64).collect()),
        ("x_mm".into(), x),
        ("ex_um".into(), vec![0.0; n]),
    ])
    .unwrap();
    let ctx = Context::from_recording(&rec);
    let spike = Candidate {
        axis: 'x',
        kind: Kind::ReversalSpike,
        grid: log_grid(0.05, 20.0, 1.5),
    };
    let f = ctx.axis('x').unwrap();
    let dist = f.dist_since_rev_mm();
    assert!(f.dir.contains(&-1) && dist.iter().any(|&s| s < 1.0));
    let want: Vec<(u64, Vec<u64>)> = spike
        .grid
        .iter()
        .map(|&decay| {
            let col = f
                .dir
                .iter()
                .zip(&dist)
                .map(|(&d, s)| f64::from(d) * (-s / decay).exp());
            (decay.to_bits(), col.map(f64::to_bits).collect())
        })
        .collect();
    assert_sweep_is(&ctx, &spike, &want);
}

/// `c`'s one-column sweep over its grid hands `f` (θ, column) of `want`, bit for bit, on one
/// thread and on three, and `Candidate::columns` at each θ is the same column.
fn assert_sweep_is(ctx: &Context, c: &Candidate, want: &[(u64, Vec<u64>)]) {
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<u64>>();
    for threads in [1, 3] {
        let pool = crate::diagnose::test_pool(threads);
        let got = pool.install(|| {
            c.par_sweep_map(ctx, &c.grid, |theta, cols| {
                assert_eq!(cols.len(), 1);
                ((theta.to_bits(), bits(&cols[0])), cols)
            })
        });
        assert_eq!(got, want, "{} on {threads} threads", c.label());
    }
    for (&theta, (_, col)) in c.grid.iter().zip(want) {
        assert_eq!(
            &bits(&c.columns(ctx, theta)[0]),
            col,
            "{} at {theta}",
            c.label()
        );
    }
}
