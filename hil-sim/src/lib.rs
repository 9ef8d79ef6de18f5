//! hil-sim: a virtual legacy CNC that hides real physics and speaks the field buses.
//!
//! Sans-IO core: [`world::World`] is a deterministic stepped world (legacy controller, true machine
//! and sensors) advanced by `step(dt)`. Shells around it: the recording writer ([`recording`]), the
//! clock ([`clock`]), and the bus servers ([`io`]).
//!
//! Sign convention everywhere: error = actual − nominal (ISO 230-2) in µm; an origin shift of
//! +n LSB moves the slide by +n·LSB; a correction is the negated error.
// Unit suffixes keep SI capitalisation (`_C`, `_K`, `_N`) as the project's column names do.
#![allow(non_snake_case)]
// Per-axis loops index several [f64; 3] arrays at once; `for k in 0..3` reads clearest.
#![allow(clippy::needless_range_loop)]
#![warn(
    unreachable_pub,
    unnameable_types,
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    clippy::cast_possible_wrap,
    clippy::float_cmp
)]
#![cfg_attr(
    test,
    allow(
        clippy::float_cmp,
        reason = "tests assert values that are exact in binary or parsed from the same decimal text"
    )
)]

pub mod artefacts;
pub mod cases;
pub mod cli;
pub mod clock;
pub mod compensators;
pub mod config;
pub mod controller;
pub mod harness;
pub mod io;
pub mod manifest;
pub mod physics;
pub mod recording;
pub mod rng;
pub mod truth;
pub mod world;

pub use config::SimConfig;
pub use world::World;
