//! The model crate's integration tests, one binary: the hand-specialised floor gives `evaluate`'s
//! breakdown (`floor`), and no evaluation allocates (`no_alloc`, counted per thread by the
//! allocator below). A test is `cargo test -p retrocomp-model --test model <module>::`.

#[path = "../../benches/floor_vmc/mod.rs"]
mod floor_vmc;

// The one counting allocator of the workspace's no-allocation tests.
#[path = "../../../../tests/gateway_support/counting_alloc.rs"]
mod counting_alloc;

#[global_allocator]
static GLOBAL: counting_alloc::Counting = counting_alloc::Counting;

mod floor;
mod no_alloc;
