//! Shrinking camera frames by area averaging: each output pixel is the mean of the source
//! pixels it covers (fractional edges weighted by their overlap), the way a camera with
//! larger pixels would integrate the same light.

use optalign_optics::Frame;

/// For each output cell along one side, the source pixels it covers and their weights.
fn coverage(source: usize, target: usize) -> Vec<Vec<(usize, f32)>> {
    let ratio = source as f64 / target as f64;
    (0..target)
        .map(|cell| {
            let (start, end) = (cell as f64 * ratio, (cell + 1) as f64 * ratio);
            (start.floor() as usize..(end.ceil() as usize).min(source))
                .map(|pixel| {
                    let overlap = end.min(pixel as f64 + 1.0) - start.max(pixel as f64);
                    (pixel, (overlap / ratio) as f32)
                })
                .filter(|&(_, weight)| weight > 0.0)
                .collect()
        })
        .collect()
}

/// The frame averaged down to `width` x `height` (each at most the frame's own side).
pub fn area_average(frame: &Frame, width: u32, height: u32) -> anyhow::Result<Frame> {
    anyhow::ensure!(
        (1..=frame.width()).contains(&width) && (1..=frame.height()).contains(&height),
        "cannot average a {}x{} frame down to {width}x{height}: each side must be 1 up to the frame's",
        frame.width(),
        frame.height()
    );
    let (source_w, w, h) = (frame.width() as usize, width as usize, height as usize);
    let columns = coverage(source_w, w);
    let rows = coverage(frame.height() as usize, h);
    let mut row_sums = vec![0f32; w];
    let mut out = Vec::with_capacity(w * h);
    let full_scale = f32::from(frame.full_scale());
    for row_cover in &rows {
        row_sums.fill(0.0);
        for &(y, row_weight) in row_cover {
            let source_row = &frame.pixels()[y * source_w..(y + 1) * source_w];
            for (sum, cover) in row_sums.iter_mut().zip(&columns) {
                let across: f32 = cover
                    .iter()
                    .map(|&(x, weight)| f32::from(source_row[x]) * weight)
                    .sum();
                *sum += across * row_weight;
            }
        }
        out.extend(
            row_sums
                .iter()
                .map(|&v| v.round().clamp(0.0, full_scale) as u16),
        );
    }
    Ok(Frame::deep(width, height, out, frame.full_scale())?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_average_to_their_mean_and_fractions_weigh_by_overlap() {
        let frame = Frame::new(4, 2, vec![0, 100, 200, 40, 10, 30, 60, 80]).unwrap();
        let halved = area_average(&frame, 2, 1).unwrap();
        assert_eq!(halved.pixels(), &[35, 95]);
        let thirds = area_average(&Frame::new(3, 1, vec![0, 90, 180]).unwrap(), 2, 1).unwrap();
        assert_eq!(thirds.pixels(), &[30, 150]);
        assert_eq!(area_average(&frame, 4, 2).unwrap(), frame);
    }

    #[test]
    fn growing_a_frame_is_refused() {
        let frame = Frame::new(4, 2, vec![0; 8]).unwrap();
        let error = area_average(&frame, 8, 2).unwrap_err().to_string();
        assert!(error.contains("4x2 frame down to 8x2"), "{error}");
        assert!(area_average(&frame, 0, 1).is_err());
    }
}
