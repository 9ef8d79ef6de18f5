//! Modbus register decoding: arbitrary words for every type and word order, through the poll core.
#![no_main]

use libfuzzer_sys::fuzz_target;
use retrocomp_bus::modbus::{
    DataType, PollCore, ReadOutcome, RegisterChannel, RegisterTable, WordOrder, decode_raw,
};

fuzz_target!(|data: &[u8]| {
    let Some((&sel, rest)) = data.split_first() else { return };
    let words: Vec<u16> = rest.chunks_exact(2).map(|c| u16::from_be_bytes([c[0], c[1]])).collect();
    let types = [DataType::Int16, DataType::Uint16, DataType::Int32, DataType::Uint32, DataType::Float32];
    let t = types[usize::from(sel % 5)];
    let wo = if sel & 0x80 != 0 { WordOrder::LowFirst } else { WordOrder::HighFirst };
    let _ = decode_raw(&words, t, wo);
    let chans: Vec<RegisterChannel> = (0..4u16)
        .map(|i| RegisterChannel {
            channel: format!("c{i}_C"),
            kind: if i % 2 == 0 { RegisterTable::Input } else { RegisterTable::Holding },
            address: u16::from(sel >> 3) + 2 * i,
            data_type: t,
            word_order: wo,
            scale: 0.1,
            offset: 0.0,
            min: Some(-100.0),
            max: Some(100.0),
        })
        .collect();
    let mut core = PollCore::new(chans, &mut retrocomp_bus::ChannelTable::default(), 125, u16::from(sel & 7));
    let mut out = Vec::new();
    for b in 0..core.plan.len() {
        core.handle_outcome(b, &ReadOutcome::Registers(words.clone()), 0.0, &mut out);
    }
    assert_eq!(out.len(), 4);
});
