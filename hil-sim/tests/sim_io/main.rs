//! The simulator on real transports, one test binary: its own transports on loopback and ptys
//! (`transports`: Modbus TCP with the PMC-style handshake, Modbus RTU on a pty, CiA 406/404 on the
//! in-memory bus and through a socketcand hub, weighing lines), and third-party peers reading them
//! (`pycan`: python-can through socketcand; `peers`: mbpoll over TCP and RTU). A test is
//! `cargo test -p hil-sim --test sim_io <module>::`. Every test makes its own simulator, hub and
//! ports, so tests of the three files may run side by side.

mod peers;
mod pycan;
mod transports;
