//! Instructions per exact evaluation of vmc-3axis: `MachineModel::evaluate` and the floor
//! (`benches/floor_vmc`), counted by valgrind in one run of this program (issue 39, point 1).
//!
//! `cargo run --profile bench -p retrocomp-model --example floor_count [-- N]` runs itself three
//! times under `valgrind --tool=cachegrind --cache-sim=no`: N iterations of the bench's loop
//! (next point, time + 1 ms) with no evaluation, with `evaluate`, and with the floor; it prints
//! (I_plan − I_loop) / N and (I_floor − I_loop) / N and their ratio. N defaults to 200 000.
//! `floor_count loop|plan|floor N` is one such run, without valgrind.

#[path = "../benches/floor_vmc/mod.rs"]
mod floor_vmc;

use std::hint::black_box;
use std::process::Command;

use retrocomp_model::ModelInput;

fn run(mode: &str, n: usize) {
    let m = floor_vmc::vmc_model();
    let floor = floor_vmc::Floor::new(&m);
    let mut pts = floor_vmc::bench_inputs(&m, 4096);
    let (mut state, mut fstate) = (m.new_state(), floor.new_state());
    let mut out = m.new_breakdown();
    let mut t = 0.0;
    let mut each = |eval: &mut dyn FnMut(&ModelInput)| {
        for k in 0..n {
            let input = &mut pts[k & 4095];
            t += 0.001;
            input.t_s = t;
            eval(black_box(&*input));
        }
    };
    match mode {
        "loop" => each(&mut |input| {
            black_box(input);
        }),
        "plan" => each(&mut |input| {
            m.evaluate(input, &mut state, &mut out);
            black_box(&out);
        }),
        "floor" => each(&mut |input| {
            floor.run(input, &mut fstate, &mut out);
            black_box(&out);
        }),
        _ => panic!("mode: loop, plan or floor"),
    }
}

/// Instructions (cachegrind's `I refs`) of `self mode n`.
fn instructions(exe: &str, mode: &str, n: usize) -> u64 {
    let o = Command::new("valgrind")
        .args([
            "--tool=cachegrind",
            "--cache-sim=no",
            "--cachegrind-out-file=/dev/null",
        ])
        .args([exe, mode, &n.to_string()])
        .output()
        .expect("valgrind runs (apt-get install valgrind)");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let line = err
        .lines()
        .find(|l| l.contains("I refs:") || l.contains("I   refs:"))
        .unwrap_or_else(|| panic!("no I refs in {err}"));
    let digits: String = line
        .split(':')
        .nth(1)
        .expect("a count")
        .chars()
        .filter(char::is_ascii_digit)
        .collect();
    digits.parse().expect("a number")
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if let [_, mode, n] = &args[..] {
        run(mode, n.parse().expect("N"));
        return;
    }
    let n: usize = args.get(1).map_or(200_000, |n| n.parse().expect("N"));
    let [base, plan, floor] = ["loop", "plan", "floor"].map(|mode| instructions(&args[0], mode, n));
    #[allow(clippy::cast_precision_loss, reason = "instruction counts < 2⁵³")]
    let per = |i: u64| (i - base) as f64 / n as f64;
    let (p, f) = (per(plan), per(floor));
    println!("N = {n}: loop alone {base} instructions");
    println!("evaluate: {p:.0} instructions per evaluation");
    println!("floor:    {f:.0} instructions per evaluation");
    println!("ratio:    {:.2}", p / f);
}
