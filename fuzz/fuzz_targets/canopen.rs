//! CANopen decoders (NMT, heartbeat, SDO, CiA 406 position, CiA 404 analog) on arbitrary frames.
#![no_main]

use libfuzzer_sys::fuzz_target;
use retrocomp_bus::can::Frame;
use retrocomp_bus::canopen::{
    AnalogChannel, AnalogType, CountingDirection, EncoderChannel, PositionDecoder, SdoRequest,
    SdoResponse, decode_heartbeat, decode_nmt,
};

fuzz_target!(|data: &[u8]| {
    if data.len() < 6 {
        return;
    }
    let (hdr, rest) = data.split_at(6);
    let id = u32::from_le_bytes([hdr[0], hdr[1], hdr[2], hdr[3]]);
    let payload = &rest[..rest.len().min(8)];
    let f = if hdr[4] & 1 == 1 {
        Frame::extended(id & 0x1FFF_FFFF, payload)
    } else {
        Frame::standard((id & 0x7FF) as u16, payload)
    };
    let Some(f) = f else { return };
    let _ = decode_nmt(&f);
    let _ = decode_heartbeat(&f);
    if let Some((n, r)) = SdoRequest::decode(&f) {
        assert_eq!(SdoRequest::decode(&r.encode(n)), Some((n, r)));
    }
    if let Some((n, r)) = SdoResponse::decode(&f) {
        assert_eq!(SdoResponse::decode(&r.encode(n)), Some((n, r)));
    }
    let node = (hdr[5] & 0x7F).max(1);
    let mut table = retrocomp_bus::ChannelTable::default();
    let mut dec = PositionDecoder::new(EncoderChannel {
        channel: "x_mm".into(),
        node_id: node,
        tpdo: 1 + (hdr[4] >> 6),
        byte_offset: (hdr[4] >> 1) & 3,
        counts_per_mm: 1000.0,
        direction: CountingDirection::Negative,
        offset_mm: 0.0,
        total_range_counts: Some(u64::from(id).max(2)),
        cyclic_ms: None,
        min_mm: None,
        max_mm: None,
    }, &mut table);
    let _ = dec.decode(&f, 0.0);
    let a = AnalogChannel {
        channel: "T_C".into(),
        node_id: node,
        tpdo: 1,
        byte_offset: hdr[4] >> 4,
        data_type: [AnalogType::Int16, AnalogType::Int32, AnalogType::Real32][usize::from(hdr[5] % 3)],
        decimal_digits: hdr[5] >> 3,
        min: None,
        max: None,
    };
    let _ = a.decode(table.resolve("T_C"), &f, 0.0);
});
