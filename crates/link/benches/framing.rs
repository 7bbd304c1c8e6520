//! Framing throughput: XBee API encode/parse (mode 2), SLIP, and ARQ
//! segmentation of a 30 kB message.

// criterion_group! and criterion_main! define undocumented public items.
#![allow(missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use std::hint::black_box;
use stereolink_link::arq::{Config, Sender, SessionId};
use stereolink_link::xbee::{ApiMode, Frame, Parser};

fn framing(c: &mut Criterion) {
    let frame = Frame::Tx16 {
        frame_id: 1,
        dest: 0x7D11,
        options: 0,
        data: (0..100u8).collect(),
    };
    let wire: Vec<u8> = (0..100)
        .flat_map(|_| frame.encode(ApiMode::Escaped))
        .collect();
    let mut g = c.benchmark_group("framing");
    g.throughput(Throughput::Bytes(wire.len() as u64));
    g.bench_function("xbee_encode_mode2", |b| {
        b.iter(|| {
            (0..100)
                .map(|_| black_box(&frame).encode(ApiMode::Escaped).len())
                .sum::<usize>()
        })
    });
    g.bench_function("xbee_parse_mode2", |b| {
        b.iter(|| {
            let mut p = Parser::new(ApiMode::Escaped);
            black_box(&wire).iter().filter_map(|&x| p.push(x)).count()
        })
    });
    g.bench_function("slip_encode", |b| {
        b.iter(|| {
            (0..100)
                .map(|_| stereolink_link::slip::encode(black_box(&wire[..100])).len())
                .sum::<usize>()
        })
    });
    let msg = vec![0x5Au8; 30_000];
    g.throughput(Throughput::Bytes(msg.len() as u64));
    g.bench_function("arq_fragment_30k", |b| {
        b.iter(|| {
            let mut s = Sender::new(
                Config {
                    window: usize::MAX,
                    ..Config::for_mtu(100)
                },
                SessionId(1),
            );
            s.start(black_box(&msg), 0).unwrap();
            std::iter::from_fn(|| s.poll_transmit(0)).count()
        })
    });
    g.finish();
}

criterion_group!(benches, framing);
criterion_main!(benches);
