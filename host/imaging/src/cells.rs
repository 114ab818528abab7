//! Sums over a grid of square cells in one pass over an image, and a cell's neighbours.

/// Sums (of type `S`) and pixel counts of an image's values over square cells, row-major.
pub(crate) struct CellSums<S> {
    pub columns: usize,
    pub rows: usize,
    pub sums: Vec<S>,
    pub counts: Vec<f64>,
}

impl<S: Clone + Default + std::ops::AddAssign> CellSums<S> {
    /// Sums `values` (`width` wide) over cells of side `cell`, each row's run by `run_sum`.
    pub(crate) fn new<T>(
        values: &[T],
        width: usize,
        height: usize,
        cell: usize,
        run_sum: impl Fn(&[T]) -> S,
    ) -> Self {
        let (columns, rows) = (width.div_ceil(cell), height.div_ceil(cell));
        let mut sums = vec![S::default(); columns * rows];
        let mut counts = vec![0f64; columns * rows];
        for (y, row) in values.chunks_exact(width).enumerate() {
            let base = (y / cell) * columns;
            for (c, chunk) in row.chunks(cell).enumerate() {
                sums[base + c] += run_sum(chunk);
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
}

impl CellSums<f64> {
    /// Each cell's mean, row-major.
    pub(crate) fn means(&self) -> impl Iterator<Item = f64> + '_ {
        self.sums
            .iter()
            .zip(&self.counts)
            .map(|(s, n)| s / n.max(1.0))
    }
}

pub(crate) fn f64_sum<T: Copy + Into<f64>>(run: &[T]) -> f64 {
    run.iter().map(|&v| v.into()).sum::<f64>()
}

/// The cells within `reach` of cell `i` (itself included) of a `w` x `h` grid, row by row.
pub(crate) fn around(i: usize, reach: usize, w: usize, h: usize) -> impl Iterator<Item = usize> {
    let (x, y) = (i % w, i / w);
    (y.saturating_sub(reach)..(y + reach + 1).min(h)).flat_map(move |ny| {
        (x.saturating_sub(reach)..(x + reach + 1).min(w)).map(move |nx| ny * w + nx)
    })
}
