//! Modbus sources and server: the register map and its sans-IO conversion ([`regmap`]), the register-word vocabulary shared by every
//! Modbus map in the workspace ([`words`]), the sans-IO
//! poll core ([`poll_core`]) and its schedule ([`poll_schedule`]: when to connect and read), the one checked register read of every client ([`read`]), the polling client over tokio-modbus TCP/RTU ([`poller`]), and a small
//! register server ([`server`]).

pub mod poll_core;
pub mod poll_schedule;
pub mod poller;
pub mod read;
pub mod regmap;
pub mod server;
pub mod tcp_conn;
pub mod words;

pub use poller::{ModbusPoller, ModbusSourceConfig, TransportKind};
pub use regmap::{RegisterChannel, RegisterTable};
pub use server::{RegisterBank, TcpServer};
pub use words::{DataType, WordOrder};
