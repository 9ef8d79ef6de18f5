//! No panic on any input, for every bus decoder and parser, with 10^5 cases each, plus encode→decode
//! round trips where an encoder exists.

use proptest::prelude::*;
use retrocomp_bus::can::Frame;
use retrocomp_bus::can::socketcand::{Decoder, Message, encode, parse_message};
use retrocomp_bus::canopen::{
    AnalogChannel, AnalogType, CountingDirection, EncoderChannel, PositionDecoder, SdoRequest,
    SdoResponse, decode_heartbeat, decode_nmt,
};
use retrocomp_bus::modbus::{
    DataType, PollCore, ReadOutcome, RegisterChannel, RegisterTable, WordOrder, decode_raw,
    encode_raw,
};
use retrocomp_bus::serial::{
    GenericFormat, LineFramer, parse_generic, parse_heidenhain, parse_mitutoyo, parse_nd522,
    parse_weighing,
};
use retrocomp_bus::{ChannelTable, Health};

const CASES: u32 = 100_000;

fn cfg() -> ProptestConfig {
    ProptestConfig {
        cases: CASES,
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

fn any_frame() -> impl Strategy<Value = Frame> {
    (
        any::<bool>(),
        any::<u32>(),
        proptest::collection::vec(any::<u8>(), 0..=8),
    )
        .prop_map(|(ext, id, d)| {
            if ext {
                Frame::extended(id & 0x1FFF_FFFF, &d).unwrap()
            } else {
                Frame::standard((id & 0x7FF) as u16, &d).unwrap()
            }
        })
}

/// Bytes biased towards the protocol's alphabet so the parser's deeper branches are reached.
fn socketcand_bytes() -> impl Strategy<Value = Vec<u8>> {
    let tok = prop_oneof![
        Just(b"< ".to_vec()),
        Just(b" >".to_vec()),
        Just(b"send ".to_vec()),
        Just(b"frame ".to_vec()),
        Just(b"181 ".to_vec()),
        Just(b"18FF50E5 ".to_vec()),
        Just(b"4 ".to_vec()),
        Just(b"1.5 ".to_vec()),
        "[0-9a-fA-F]{1,3} ".prop_map(String::into_bytes),
        proptest::collection::vec(any::<u8>(), 0..4),
    ];
    proptest::collection::vec(tok, 0..24).prop_map(|v| v.concat())
}

proptest! {
    #![proptest_config(cfg())]

    #[test]
    fn socketcand_decoder_never_panics(chunks in proptest::collection::vec(socketcand_bytes(), 1..4)) {
        let mut d = Decoder::new();
        for c in &chunks {
            d.push(c);
            while let Some(m) = d.next_message() {
                // What parsed must re-encode to something that parses to the same message.
                if let Ok(m @ (Message::Send(_) | Message::Frame { .. })) = m {
                    let wire = encode(&m);
                    let inner = &wire[1..wire.len() - 1];
                    let back = parse_message(inner).unwrap();
                    match (&m, &back) {
                        (Message::Frame { frame: a, t_s: ta }, Message::Frame { frame: b, t_s: tb }) => {
                            prop_assert_eq!(a, b);
                            // µs resolution on the wire; past ~1e15 s an f64 has no µs digits left.
                            prop_assert!((ta - tb).abs() <= 1e-6 * ta.max(1.0) || *ta > 1e15);
                        }
                        _ => prop_assert_eq!(&m, &back),
                    }
                }
            }
            prop_assert!(d.pending() <= retrocomp_bus::can::socketcand::MAX_MESSAGE_LEN + 2 + c.len());
        }
    }

    #[test]
    fn socketcand_send_round_trip(f in any_frame()) {
        let wire = encode(&Message::Send(f));
        let mut d = Decoder::new();
        d.push(wire.as_bytes());
        prop_assert_eq!(d.next_message(), Some(Ok(Message::Send(f))));
    }

    #[test]
    fn canopen_decoders_never_panic(f in any_frame(), node in 1u8..=127, off in 0u8..=8, range in 2u64..=(1u64 << 32), digits in 0u8..=12, t in 0usize..3) {
        let _ = decode_nmt(&f);
        let _ = decode_heartbeat(&f);
        if let Some((n, r)) = SdoRequest::decode(&f) {
            prop_assert_eq!(SdoRequest::decode(&r.encode(n)), Some((n, r)));
        }
        if let Some((n, r)) = SdoResponse::decode(&f) {
            prop_assert_eq!(SdoResponse::decode(&r.encode(n)), Some((n, r)));
        }
        let enc = EncoderChannel {
            channel: "x_mm".into(), node_id: node, tpdo: 1, byte_offset: off.min(4), counts_per_mm: 1000.0,
            direction: CountingDirection::Negative, offset_mm: 1.0, total_range_counts: Some(range), cyclic_ms: None,
            min_mm: None, max_mm: None,
        };
        let mut dec = PositionDecoder::new(enc, &mut ChannelTable::default());
        let _ = dec.decode(&f, 0.0);
        let _ = dec.decode(&f, 0.0);
        let a = AnalogChannel {
            channel: "T_C".into(), node_id: node, tpdo: 1, byte_offset: off,
            data_type: [AnalogType::Int16, AnalogType::Int32, AnalogType::Real32][t],
            decimal_digits: digits, min: None, max: None,
        };
        let _ = a.decode(ChannelTable::default().resolve("T_C"), &f, 0.0);
    }

    #[test]
    fn cia406_position_round_trip(counts in -(1i64 << 30)..(1i64 << 30), neg in any::<bool>(), off in -1000.0f64..1000.0) {
        let enc = EncoderChannel {
            channel: "x_mm".into(), node_id: 5, tpdo: 1, byte_offset: 0, counts_per_mm: 1000.0,
            direction: if neg { CountingDirection::Negative } else { CountingDirection::Positive }, offset_mm: off,
            total_range_counts: None, cyclic_ms: None, min_mm: None, max_mm: None,
        };
        let mm = counts as f64 / 1000.0;
        let mut dec = PositionDecoder::new(enc.clone(), &mut ChannelTable::default());
        let s = dec.decode(&enc.encode_position(mm).unwrap(), 0.0).unwrap();
        prop_assert_eq!(s.health, Health::Ok);
        prop_assert!((s.value - mm).abs() <= 0.5e-3 + 1e-9 * mm.abs(), "{} vs {}", s.value, mm);
    }

    #[test]
    fn modbus_register_decoding_never_panics(words in proptest::collection::vec(any::<u16>(), 0..6), t in 0usize..5, cdab in any::<bool>(), scale in -1e3f64..1e3, start in 0u16..8) {
        let dt = [DataType::Int16, DataType::Uint16, DataType::Int32, DataType::Uint32, DataType::Float32][t];
        let wo = if cdab { WordOrder::LowFirst } else { WordOrder::HighFirst };
        if let Some(raw) = decode_raw(&words, dt, wo)
            && dt != DataType::Float32
        {
            let (w, n) = encode_raw(raw, dt, wo).unwrap();
            prop_assert_eq!(&w[..n], &words[..]);
        }
        let chans: Vec<RegisterChannel> = (0..3).map(|i| RegisterChannel {
            channel: format!("c{i}_C"), kind: RegisterTable::Input, address: start + 2 * i, data_type: dt,
            word_order: wo, scale, offset: 0.5, min: Some(-10.0), max: Some(10.0),
        }).collect();
        let mut core = PollCore::new(chans, &mut ChannelTable::default(), 125, 1);
        let mut out = Vec::new();
        for b in 0..core.plan.len() {
            core.handle_outcome(b, &ReadOutcome::Registers(words.clone()), 0.0, &mut out);
        }
        prop_assert_eq!(out.len(), 3);
        for s in &out {
            prop_assert!(s.health != Health::Ok || s.value.is_finite());
        }
    }

    #[test]
    fn serial_parsers_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..96), decimals in 0u8..=12) {
        let mut f = LineFramer::new(32);
        let mut lines = Vec::new();
        f.push(&bytes, |l| lines.push(l.to_vec()));
        prop_assert!(f.partial_len() <= 32);
        let g = GenericFormat { prefix: None, delimiter: Some(",".into()), unit: Some("C".into()) };
        prop_assert!(lines.iter().all(|l| !l.is_empty() && !l.contains(&b'\n') && !l.contains(&b'\r')));
        // Parsers get both the framed lines and the raw bytes (which may hold anything).
        for l in lines.iter().chain(std::iter::once(&bytes)) {
            let _ = parse_heidenhain(l, decimals);
            for r in [parse_nd522(l), parse_mitutoyo(l)].into_iter().flatten() {
                prop_assert!(r.value.is_finite());
            }
            let _ = parse_weighing(l, Some("kg"));
            if let Ok(rs) = parse_generic(l, &g) {
                prop_assert!(rs.iter().all(|r| r.value.is_finite()));
            }
        }
    }

    #[test]
    fn serial_formats_accept_what_instruments_send(v in -99_999_999i64..=99_999_999, ch in 0u8..=99) {
        let s = format!("\u{2}{}{:09}", if v < 0 { '-' } else { '+' }, v.abs());
        prop_assert_eq!(parse_heidenhain(s.as_bytes(), 3).unwrap().value, v as f64 / 1000.0);
        let m = format!("{ch:02}A{}{:08.3}", if v < 0 { '-' } else { '+' }, (v.abs() % 10_000_000) as f64 / 1000.0);
        let r = parse_mitutoyo(m.as_bytes()).unwrap();
        prop_assert_eq!(r.key, Some(ch.to_string()));
        prop_assert!((r.value.abs() - (v.abs() % 10_000_000) as f64 / 1000.0).abs() < 1e-9);
    }
}
