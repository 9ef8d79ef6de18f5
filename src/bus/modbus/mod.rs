//! Modbus sources and server: the register map and its sans-IO conversion ([`regmap`]), the polling
//! client over tokio-modbus TCP/RTU ([`poller`]), and a small register server ([`server`]).

pub mod regmap;
pub mod server;

pub use regmap::{DataType, RegisterChannel, RegisterKind, WordOrder};
pub use server::{RegisterBank, TcpServer};
