//! Modbus sources and server: the register map and its sans-IO conversion ([`RegisterChannel`],
//! [`decode_raw`]), the register-word vocabulary shared by every Modbus map in the workspace
//! ([`DataType`], [`WordOrder`]), the sans-IO poll core ([`PollCore`]) and its schedule
//! ([`PollSchedule`]: when to connect and read), the one checked register read of every client
//! ([`read_registers`]), the polling client over tokio-modbus TCP/RTU ([`ModbusPoller`]), and a small
//! register server ([`RegisterBank`], [`TcpServer`], [`spawn_rtu`]).

mod poll_core;
mod poll_schedule;
mod poller;
mod read;
mod regmap;
mod server;
mod tcp_conn;
mod words;

pub use poll_core::{PollCore, PollCounters, ReadOutcome};
pub use poll_schedule::{PollRequest, PollSchedule, PollStep};
pub use poller::{ModbusPoller, ModbusSourceConfig, Parity, TransportKind};
pub use read::read_registers;
pub use regmap::{ReadBlock, RegisterChannel, RegisterTable, decode_raw, encode_raw};
pub use server::{RegisterBank, RegisterService, TcpServer, spawn_rtu};
pub use words::{DataType, WordOrder, split_u32, warn_deprecated_spellings};
