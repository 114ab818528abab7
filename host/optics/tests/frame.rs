//! Frames: PNG round trip and size checks.

use optalign_optics::scenario::MichelsonParams;
use optalign_optics::{Frame, FrameError, Michelson};

#[test]
fn png_round_trip_preserves_every_pixel() {
    let scene = Michelson::new(MichelsonParams::default(), [0; 4]).unwrap();
    let frame = scene.render(&[0; 4], 0);
    let png = frame.encode_png().unwrap();
    assert_eq!(&png[1..4], b"PNG");
    assert_eq!(Frame::decode_png(&png).unwrap(), frame);
}

#[test]
fn buffer_must_match_the_size() {
    assert!(matches!(
        Frame::new(4, 3, vec![0; 11]),
        Err(FrameError::Size {
            expected: 12,
            got: 11,
            ..
        })
    ));
    let f = Frame::new(2, 2, vec![1, 2, 3, 4]).unwrap();
    assert_eq!((f.width(), f.height(), f.pixel(1, 1)), (2, 2, 4));
}

#[test]
fn garbage_is_not_a_png() {
    assert!(matches!(
        Frame::decode_png(b"not a png"),
        Err(FrameError::Png(_))
    ));
}
