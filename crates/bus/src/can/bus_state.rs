//! Sans-IO CAN controller state from error frames: error-active → warning → passive → bus-off and
//! back, the controller's error counters, and how many error frames arrived.
//!
//! Both backends feed it. SocketCAN delivers the kernel's error frames (`CAN_ERR_FLAG` set, class
//! bits in the id, details in the data: linux/can/error.h); a socketcand daemon forwards them as
//! `< error <class-hex> <sec>.<usec> >` with the class only (socketcand `state_raw.c`), so over
//! socketcand bus-off and restarts are seen, error-passive and the counters are not.
//!
//! State rules (the kernel reports changes, not levels): `BUSOFF` → bus-off; `RESTARTED` or
//! `CRTL_ACTIVE` → active; `CRTL_*_PASSIVE` → passive; `CRTL_*_WARNING` → warning. A data frame
//! received while bus-off also ends it: a controller that is off the bus receives nothing, so the
//! frame proves it rejoined (drivers with `restart-ms` do not always send `RESTARTED`).

/// linux/can/error.h error classes (in the error frame's id).
pub(crate) const CAN_ERR_CRTL: u32 = 0x0004;
pub const CAN_ERR_BUSOFF: u32 = 0x0040;
pub(crate) const CAN_ERR_RESTARTED: u32 = 0x0100;
pub(crate) const CAN_ERR_CNT: u32 = 0x0200;
/// data[1] bits of a `CAN_ERR_CRTL` frame.
const CRTL_RX_WARNING: u8 = 0x04;
const CRTL_TX_WARNING: u8 = 0x08;
const CRTL_RX_PASSIVE: u8 = 0x10;
const CRTL_TX_PASSIVE: u8 = 0x20;
const CRTL_ACTIVE: u8 = 0x40;

/// One error frame: the class bits (`can_id & CAN_ERR_MASK`) and the 8 data bytes (zeros when the
/// transport does not carry them, as over socketcand).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ErrorFrame {
    pub class: u32,
    pub data: [u8; 8],
}

impl ErrorFrame {
    pub fn class_only(class: u32) -> Self {
        ErrorFrame {
            class,
            data: [0; 8],
        }
    }
}

/// The controller's fault confinement state (ISO 11898-1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BusState {
    #[default]
    Active,
    Warning,
    Passive,
    BusOff,
}

/// What the error frames say about the bus, accumulated since the backend was opened.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BusErrors {
    state: BusState,
    /// Error frames received (every class).
    pub error_frames: u64,
    /// Times the controller went bus-off.
    pub bus_off_events: u64,
    /// Last transmit / receive error counter reported (`CAN_ERR_CNT`); None until one is.
    pub tx_error_count: Option<u8>,
    pub rx_error_count: Option<u8>,
}

impl BusErrors {
    pub fn state(&self) -> BusState {
        self.state
    }

    pub fn handle_error_frame(&mut self, f: &ErrorFrame) {
        self.error_frames += 1;
        if f.class & CAN_ERR_CNT != 0 {
            self.tx_error_count = Some(f.data[6]);
            self.rx_error_count = Some(f.data[7]);
        }
        if f.class & CAN_ERR_BUSOFF != 0 {
            if self.state != BusState::BusOff {
                self.bus_off_events += 1;
            }
            self.state = BusState::BusOff;
            return;
        }
        if f.class & CAN_ERR_RESTARTED != 0 {
            self.state = BusState::Active;
        }
        if f.class & CAN_ERR_CRTL != 0 {
            let d = f.data[1];
            if d & CRTL_ACTIVE != 0 {
                self.state = BusState::Active;
            } else if d & (CRTL_RX_PASSIVE | CRTL_TX_PASSIVE) != 0 {
                self.state = BusState::Passive;
            } else if d & (CRTL_RX_WARNING | CRTL_TX_WARNING) != 0 {
                self.state = BusState::Warning;
            }
        }
    }

    /// A data or remote frame arrived: the controller is on the bus.
    pub fn handle_frame(&mut self) {
        if self.state == BusState::BusOff {
            self.state = BusState::Active;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn crtl(d1: u8) -> ErrorFrame {
        let mut data = [0; 8];
        data[1] = d1;
        ErrorFrame {
            class: CAN_ERR_CRTL,
            data,
        }
    }

    #[test]
    fn walks_active_warning_passive_busoff_and_back() {
        let mut b = BusErrors::default();
        b.handle_error_frame(&crtl(CRTL_TX_WARNING));
        assert_eq!(b.state(), BusState::Warning);
        b.handle_error_frame(&crtl(CRTL_RX_PASSIVE));
        assert_eq!(b.state(), BusState::Passive);
        b.handle_error_frame(&ErrorFrame::class_only(CAN_ERR_BUSOFF));
        b.handle_error_frame(&ErrorFrame::class_only(CAN_ERR_BUSOFF));
        assert_eq!((b.state(), b.bus_off_events), (BusState::BusOff, 1));
        b.handle_error_frame(&ErrorFrame::class_only(CAN_ERR_RESTARTED));
        assert_eq!(b.state(), BusState::Active);
        b.handle_error_frame(&crtl(CRTL_TX_PASSIVE));
        b.handle_error_frame(&crtl(CRTL_ACTIVE));
        assert_eq!(b.state(), BusState::Active);
        assert_eq!(b.error_frames, 7);
    }

    #[test]
    fn counters_and_a_received_frame_ending_bus_off() {
        let mut b = BusErrors::default();
        let mut f = crtl(CRTL_TX_PASSIVE);
        f.class |= CAN_ERR_CNT;
        f.data[6] = 135;
        f.data[7] = 7;
        b.handle_error_frame(&f);
        assert_eq!((b.tx_error_count, b.rx_error_count), (Some(135), Some(7)));
        b.handle_frame();
        assert_eq!(b.state(), BusState::Passive, "a frame does not end passive");
        b.handle_error_frame(&ErrorFrame::class_only(CAN_ERR_BUSOFF | CAN_ERR_CRTL));
        assert_eq!(b.state(), BusState::BusOff);
        b.handle_frame();
        assert_eq!(b.state(), BusState::Active);
    }
}
