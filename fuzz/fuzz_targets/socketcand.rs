//! socketcand rawmode decoder: arbitrary bytes, split at an arbitrary point, must never panic, and
//! every frame message that parses must survive encode → parse.
#![no_main]

use libfuzzer_sys::fuzz_target;
use retrocomp_bus::can::socketcand::{Decoder, Message, encode, parse_message};

fuzz_target!(|data: &[u8]| {
    let split = data.first().map_or(0, |b| usize::from(*b)).min(data.len());
    let mut d = Decoder::new();
    for chunk in [&data[..split], &data[split..]] {
        d.push(chunk);
        while let Some(m) = d.next_message() {
            if let Ok(m @ Message::Send(_)) = m {
                let wire = encode(&m);
                assert_eq!(parse_message(&wire[1..wire.len() - 1]), Ok(m));
            }
        }
    }
});
