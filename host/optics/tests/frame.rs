//! Frames: PNG round trips at every depth, size, depth and decoding limits.

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
        Err(FrameError::Codec(_))
    ));
}

#[test]
fn deep_frames_round_trip_at_their_depth_and_show_scaled() {
    for (bits, full_scale) in [(12, 4095), (16, u16::MAX)] {
        let mut params = MichelsonParams::default();
        params.noise.bits = bits;
        let frame = Michelson::new(params, [0; 4]).unwrap().render(&[0; 4], 0);
        assert_eq!(frame.full_scale(), full_scale);
        let png = frame.encode_png().unwrap();
        assert_eq!(Frame::decode_png(&png).unwrap(), frame, "{bits} bits");
        let shown = Frame::decode_png(&frame.encode_8bit_png().unwrap()).unwrap();
        assert_eq!(shown.full_scale(), 255);
        // The same scene at 8 bits: the scaled frame is within rounding of it.
        let eight = Michelson::new(MichelsonParams::default(), [0; 4])
            .unwrap()
            .render(&[0; 4], 0);
        let worst = shown
            .pixels()
            .iter()
            .zip(eight.pixels())
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap();
        assert!(worst <= 1, "{bits} bits: {worst}");
    }
}

#[test]
fn values_above_the_full_scale_and_huge_images_are_refused() {
    assert!(matches!(
        Frame::deep(2, 1, vec![4095, 4096], 4095),
        Err(FrameError::Depth { value: 4096, .. })
    ));
    assert!(Frame::deep(2, 1, vec![0, 1], 100).is_err());
    // 20000 px wide: refused from the header alone.
    let header = image::GrayImage::new(20_000, 1);
    let mut bytes = std::io::Cursor::new(Vec::new());
    header
        .write_to(&mut bytes, image::ImageFormat::Png)
        .unwrap();
    let error = Frame::decode_png(bytes.get_ref()).unwrap_err();
    assert!(
        matches!(error, FrameError::TooLarge { width: 20_000, .. }),
        "{error}"
    );
    assert!(error.to_string().contains("16384 px a side"), "{error}");
}
