//! Sums over a grid of square cells: what a background fit or a noise map reads an image
//! through, one pass over its pixels.

/// The sums and pixel counts of an image's values over square cells, row-major.
pub(crate) struct CellSums {
    pub columns: usize,
    pub rows: usize,
    pub sums: Vec<f64>,
    pub counts: Vec<f64>,
}

impl CellSums {
    /// Sums `values` (row-major, `width` wide, `height` high) over cells of side `cell`
    /// (the last row and column of cells may be narrower).
    pub(crate) fn new<T: Copy + Into<f64>>(
        values: &[T],
        width: usize,
        height: usize,
        cell: usize,
    ) -> Self {
        let (columns, rows) = (width.div_ceil(cell), height.div_ceil(cell));
        let mut sums = vec![0f64; columns * rows];
        let mut counts = vec![0f64; columns * rows];
        for (y, row) in values.chunks_exact(width).enumerate() {
            let base = (y / cell) * columns;
            for (c, chunk) in row.chunks(cell).enumerate() {
                sums[base + c] += chunk.iter().map(|&v| v.into()).sum::<f64>();
                counts[base + c] += chunk.len() as f64;
            }
        }
        Self {
            columns,
            rows,
            sums,
            counts,
        }
    }

    /// Each cell's mean, row-major.
    pub(crate) fn means(&self) -> impl Iterator<Item = f64> + '_ {
        self.sums
            .iter()
            .zip(&self.counts)
            .map(|(s, n)| s / n.max(1.0))
    }
}
