//! hil-sim: the virtual legacy CNC. A small clap enum + dispatch; each command's logic lives in the
//! library (`hil_sim::cli`, `hil_sim::io`, `hil_sim::cases`).

use std::path::PathBuf;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "hil-sim",
    version,
    about = "Virtual legacy CNC: hidden physics, field buses, recordings"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run a config to the end as fast as possible; write recording.csv + manifest.json.
    Run(hil_sim::cli::RunArgs),
    /// Run with the field buses up (Modbus TCP/RTU, CAN, weighing lines), real time or fast.
    Serve(hil_sim::cli::ServeArgs),
    /// Write concealed-effect cases (recording CSV + truth manifest JSON per case) for `retrocomp diagnose`.
    GenCases(hil_sim::cli::GenCasesArgs),
    /// Probe hole plates and static ball-bar spheres on a hidden machine model (Spaan's plan: six
    /// identification plates, five verification plates, eight spheres) in `retrocomp identify`'s
    /// contracts: OUT/plates, OUT/verify, OUT/ballbar.
    Artefacts {
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// The hidden machine (a machine-model TOML with the 21 geometric components).
        #[arg(long)]
        truth: PathBuf,
        /// Probing noise σ, µm.
        #[arg(long, default_value_t = 0.5)]
        noise_um: f64,
        /// Identification plan: `six` (Spaan's six measurements, the default), `seven` or `twelve`.
        #[arg(long, value_enum, default_value = "six")]
        plan: hil_sim::artefacts::Plan,
        /// Ball-bar set-ups: `eight` (Spaan Table 3.1, the default) or `ten` (plus two low
        /// spheres, dense grid); identify either with `--knot-step-mm 30 --max-knots 16`.
        #[arg(long, value_enum, default_value = "eight")]
        spheres: hil_sim::artefacts::SpherePlan,
        /// Give the hidden machine a 5 mm ball-screw lead wave on X, Y, Z (1.5 / 1.2 / 1.0 µm at
        /// 30° / 140° / −110°), probe the identification plates at pitches 0.45 lead off whole
        /// leads (62.25 × 42.25 mm), and write laser runs every 1.25 mm to OUT/laser/{x,y,z}.csv
        /// (`retrocomp identify --lead-mm 5`, `retrocomp fit axis --lead-mm 5`).
        #[arg(long)]
        lead_wave: bool,
        #[arg(long)]
        out: PathBuf,
    },
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().cmd {
        Cmd::Run(a) => hil_sim::cli::run(&a),
        Cmd::Serve(a) => hil_sim::cli::serve(&a),
        Cmd::GenCases(a) => hil_sim::cli::gen_cases(&a),
        Cmd::Artefacts {
            seed,
            truth,
            noise_um,
            plan,
            spheres,
            lead_wave,
            out,
        } => {
            use hil_sim::artefacts as art;
            let mut model = retrocomp_model::MachineModel::from_toml_path(&truth)
                .map_err(|e| anyhow::anyhow!("--truth: {e}"))?;
            if lead_wave {
                model = art::with_lead_waves(&model, &art::LEAD_WAVES);
            }
            let m = hil_sim::artefacts::Metrology {
                probing_noise_um: noise_um,
                ..Default::default()
            };
            let mut meas = hil_sim::artefacts::measure_plan(&model, &m, seed, plan);
            meas.spheres = hil_sim::artefacts::measure_spheres(&model, &m, seed, spheres);
            if lead_wave {
                let lead = art::LEAD_WAVES[0].lead_mm;
                meas.plates = art::lead_plates(lead, art::LEAD_FRACTION)
                    .iter()
                    .map(|p| art::measure_plate(&model, p, &m, seed))
                    .collect();
                art::write_laser_runs(&model, lead / 4.0, seed, &out.join("laser"))?;
            }
            let n = hil_sim::artefacts::write_all(&meas, &out)?;
            println!("wrote {n} artefact set-ups to {}", out.display());
            Ok(())
        }
    }
}
