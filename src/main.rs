//! The `retrocomp` command line: one subcommand per module in `src/cli/`. Numeric conversions
//! follow the library's rule (`src/lib.rs`): `try_from`, or an `as` with its reason.
#![warn(
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    clippy::cast_possible_wrap,
    clippy::float_cmp
)]

use clap::{Parser, Subcommand};

mod cli;

#[derive(Parser)]
#[command(
    name = "retrocomp",
    version,
    about = "Volumetric error compensation gateway for legacy CNC machines"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Load a machine model and print a summary, or every problem with file, line and key.
    CheckConfig(cli::check_config::Args),
    /// Evaluate a machine model along a path CSV; writes the errors and every term as CSV.
    Eval(cli::eval::Args),
    /// Run the gateway: sources → model → safety → origin-shift / quadrature sinks.
    Run(cli::run::Args),
    /// The main job with no hardware: hil-sim + the gateway over loopback, four runs compared
    /// (uncompensated, geometric truth, full truth, fitted from measurement runs).
    Demo(cli::demo::Args),
    /// Watch a shop of boxes over MQTT Sparkplug B: alive, compensating, degraded (docs/fleet.md).
    Fleet(cli::fleet::Args),
    /// Diagnose the fleet's recordings as one of N workers on an MQTT 5 shared subscription (docs/fleet.md).
    FleetWorker(cli::fleet_worker::Args),
    /// Send a recording to the fleet: MQTT (chunked, resumable) or a directory (docs/fleet.md).
    ShipRecording(cli::ship::Args),
    /// A socketcand-protocol CAN hub on TCP, for `hil-sim serve` and `retrocomp run` without hardware.
    Hub(cli::hub::Args),
    /// Show a running gateway's per-axis corrections, term breakdown and sensor health.
    Status(cli::status::Args),
    /// ISO 230-2:2014 positioning evaluation of one axis from laser runs.
    #[command(name = "iso230-2")]
    Iso230_2(cli::iso230_2::Args),
    /// Import laser runs or controller tables into a bidirectional error table.
    Import(cli::import::Args),
    /// Export an error table as a Fanuc pitch tape, LinuxCNC comp file or ISG CSV.
    Export(cli::export::Args),
    /// Rewrite an NC program with compensation.
    Nc(cli::nc::Args),
    /// Drip-feed an NC program to a controller's DNC serial input with live offsets (docs/dnc.md).
    Dnc(cli::dnc::Args),
    /// Circular (ballbar) test: ISO 230-4 G/F and error diagnosis.
    Circle(cli::circle::Args),
    /// Fit model terms (axis tables, thermal, load) from measurements; writes model TOML.
    Fit(cli::fit::Args),
    /// Identify the 21 geometric components from hole plates / static ball bars (Spaan Ch3).
    Identify(cli::identify::Args),
    /// Find where simulation and recording disagree, name the missing physics, fit it (docs/diagnose-json.md).
    Diagnose(cli::diagnose::DiagnoseArgs),
    /// Run diagnose over `hil-sim gen-cases` output and score it against the truth manifests.
    DiagnoseBench(cli::diagnose::BenchArgs),
}

fn main() -> std::process::ExitCode {
    let result = match Cli::parse().command {
        Command::CheckConfig(a) => cli::check_config::run(&a),
        Command::Eval(a) => cli::eval::run(&a),
        Command::Run(a) => cli::run::run(&a),
        Command::Demo(a) => cli::demo::run(&a),
        Command::Fleet(a) => cli::fleet::run(&a),
        Command::FleetWorker(a) => cli::fleet_worker::run(&a),
        Command::ShipRecording(a) => cli::ship::run(&a),
        Command::Status(a) => cli::status::run(&a),
        Command::Hub(a) => cli::hub::run(&a),
        Command::Iso230_2(a) => cli::iso230_2::run(&a),
        Command::Import(a) => cli::import::run(&a),
        Command::Export(a) => cli::export::run(&a),
        Command::Nc(a) => cli::nc::run(&a),
        Command::Dnc(a) => cli::dnc::run(&a),
        Command::Circle(a) => cli::circle::run(&a),
        Command::Fit(a) => cli::fit::run(&a),
        Command::Identify(a) => cli::identify::run(&a),
        Command::Diagnose(a) => cli::diagnose::run_diagnose(&a),
        Command::DiagnoseBench(a) => cli::diagnose::run_bench(&a),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // One line, every cause once (crates/model/src/error.rs).
            let e: &(dyn std::error::Error + 'static) = e.as_ref();
            eprintln!("error: {}", retrocomp_model::error::Chain(e));
            std::process::ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory as _;

    /// What `main` prints for a start-up error in an anyhow context: each cause once (anyhow's own
    /// `{:#}` repeats a cause whose text the layer above already embeds).
    #[test]
    fn start_up_errors_print_each_cause_once() {
        // A layer whose message embeds its cause's text, as many third-party errors do.
        let opening = anyhow::Error::new(std::io::Error::other("denied")).context("opening f.toml");
        let connecting = format!("connecting: {opening}");
        let anyhow_e = opening.context(connecting).context("start-up");
        let dyn_e: &(dyn std::error::Error + 'static) = anyhow_e.as_ref();
        assert_eq!(
            retrocomp_model::error::Chain(dyn_e).to_string(),
            "start-up: connecting: opening f.toml: denied"
        );
        assert_eq!(
            format!("{anyhow_e:#}"),
            "start-up: connecting: opening f.toml: opening f.toml: denied",
            "what main printed before"
        );
    }

    /// Every subcommand, flag and argument of the whole tree with no help text, by path.
    fn missing_help(c: &clap::Command, path: &str, out: &mut Vec<String>) {
        let path = format!("{path} {}", c.get_name());
        if c.get_about()
            .is_none_or(|a| a.to_string().trim().is_empty())
        {
            out.push(format!("{path} (the command)"));
        }
        for a in c.get_arguments() {
            let id = a.get_id().as_str();
            if matches!(id, "help" | "version") {
                continue;
            }
            if a.get_help().is_none_or(|h| h.to_string().trim().is_empty()) {
                out.push(format!("{path} {id}"));
            }
        }
        for s in c.get_subcommands() {
            missing_help(s, &path, out);
        }
    }

    #[test]
    fn every_command_flag_and_argument_has_help_text() {
        let cli = super::Cli::command();
        cli.clone().debug_assert();
        let mut missing = Vec::new();
        missing_help(&cli, "", &mut missing);
        assert!(missing.is_empty(), "no help text:\n{}", missing.join("\n"));
        // The walk sees the whole tree (a subcommand's own subcommands included).
        assert!(cli.get_subcommands().count() >= 17);
        let fit = cli.find_subcommand("fit").expect("fit");
        assert!(
            fit.get_subcommands().count() >= 2,
            "fit's subcommands are walked too"
        );
    }
}
