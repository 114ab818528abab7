//! Frame encode + decode time for a full eight-axis status reply.
use criterion::{Criterion, criterion_group, criterion_main};
use optalign_protocol::*;
use std::hint::black_box;

fn status_message() -> PeerMessage {
    let axis = AxisStatus {
        position: -12345,
        motor_steps: -12385,
        target: 4096,
        moving: true,
        direction: Direction::Positive,
        slack: Slack::TakenUpPositive,
        limits: SoftLimits {
            min: -30000,
            max: 30000,
        },
        faults: Faults(0),
        powered: true,
        underruns: 0,
    };
    let mut axes = heapless::Vec::new();
    for _ in 0..MAX_AXES {
        axes.push(axis).unwrap();
    }
    PeerMessage::Reply {
        id: RequestId(0xdead_beef),
        reply: Reply::Status(Status {
            axes,
            session: SessionState {
                trusted_link: false,
                authenticated: true,
                key_provisioned: true,
            },
            emergency_stopped: false,
            uptime_ms: 123_456_789,
            boot: BootRecord::Restored,
            storage: StorageHealth::default(),
            security: SecurityCounters::default(),
        }),
    }
}

fn bench_framing(c: &mut Criterion) {
    let message = status_message();
    let mut out = [0u8; MAX_FRAME];
    c.bench_function("status frame encode", |b| {
        b.iter(|| encode_frame(black_box(&message), &mut out).unwrap())
    });
    let len = encode_frame(&message, &mut out).unwrap();
    let frame = out[..len].to_vec();
    c.bench_function("status frame encode+decode", |b| {
        b.iter(|| {
            let len = encode_frame(black_box(&message), &mut out).unwrap();
            let mut decoder = FrameDecoder::new();
            let mut decoded = None;
            decoder.feed::<PeerMessage>(&out[..len], |m| decoded = Some(m));
            decoded.unwrap().unwrap()
        })
    });
    c.bench_function("status frame decode", |b| {
        b.iter(|| {
            let mut decoder = FrameDecoder::new();
            let mut decoded = None;
            decoder.feed::<PeerMessage>(black_box(&frame), |m| decoded = Some(m));
            decoded.unwrap().unwrap()
        })
    });
}

criterion_group!(benches, bench_framing);
criterion_main!(benches);
