//! Serial line sources: arbitrary bytes through the framer and every line format.
#![no_main]

use libfuzzer_sys::fuzz_target;
use retrocomp_bus::serial::{LineFormat, LineSource, SerialChannel, SerialSourceConfig};

fuzz_target!(|data: &[u8]| {
    let formats = [
        LineFormat::Heidenhain { decimals: 4 },
        LineFormat::Nd522,
        LineFormat::Mitutoyo,
        LineFormat::Weighing { unit: Some("kg".into()), accept_unstable: false },
        LineFormat::Generic { prefix: Some("T".into()), delimiter: Some(",".into()), unit: Some("C".into()) },
    ];
    for format in formats {
        let cfg = SerialSourceConfig {
            name: "fuzz".into(),
            device: None,
            baud: 9600,
            format,
            request: None,
            period_s: 0.1,
            timeout_s: 1.0,
            max_line: 64,
            channel: vec![SerialChannel { name: "v_mm".into(), key: None, scale: 1.0, offset: 0.0, min: None, max: None }],
        };
        let mut src = LineSource::new(cfg, &mut retrocomp_bus::ChannelTable::default());
        let mut out = Vec::new();
        src.push(data, 0.0, &mut out);
        for s in &out {
            assert!(s.health != retrocomp_bus::Health::Ok || s.value.is_finite());
        }
    }
});
