//! Beam shapes as the renderers draw them: a round or elliptical Gaussian with separable
//! factors (the fast path), or any other profile (Hermite-Gaussian modes, a doughnut, a flat
//! top, a photograph, a textured beam) as a tile of field amplitudes sampled every pixel in
//! the beam's own frame and placed with bilinear interpolation at a sub-pixel centre.
//!
//! Amplitudes peak at 1 (intensity = amplitude²) and carry the field's sign, so a
//! Hermite-Gaussian mode's lobes interfere with opposite phase.

use std::collections::HashMap;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

use crate::math::{SPOT_EXTENT, spot_span};
use crate::photo::Photo;
use crate::scenario::{BeamProfile, Texture};
use crate::speckle::SpeckleTile;

/// A 2 x 2 matrix taking a displacement in the beam's own frame to the image.
pub(crate) type Orientation = [[f64; 2]; 2];

/// Relative intensity below which a tile's rim is cut off.
const TILE_FLOOR: f64 = 1e-7;

/// A beam's shape, ready to be placed on an image.
#[derive(Debug, Clone)]
pub(crate) enum BeamShape {
    /// A Gaussian with 1/e² radii along the image axes: separable, computed directly.
    Round { radius: [f64; 2] },
    /// Any other profile.
    Tile(Tile),
}

impl BeamShape {
    /// The shape of `profile` with texture `texture`, scaled by the 1/e² radius `radius`
    /// (px, image x and y; they differ only on a sensor with non-square pixels) and turned
    /// into the image by `orientation`. `seed` fixes a speckle texture.
    pub(crate) fn new(
        profile: &BeamProfile,
        texture: &Texture,
        radius: [f64; 2],
        orientation: Orientation,
        seed: u64,
    ) -> Result<Self, String> {
        if matches!(profile, BeamProfile::Gaussian) && matches!(texture, Texture::None) {
            return Ok(Self::Round { radius });
        }
        Tile::new(profile, texture, radius, orientation, seed).map(Self::Tile)
    }

    /// The shape centred at `centre` (px) on an image of `size` (px).
    pub(crate) fn place(&self, centre: [f64; 2], size: [usize; 2]) -> Placed<'_> {
        match self {
            Self::Round { radius } => {
                let cols = spot_span(centre[0], radius[0], size[0]);
                let rows = spot_span(centre[1], radius[1], size[1]);
                let factor = |c: f64, r: f64, i: usize| {
                    let d = (i as f64 + 0.5 - c) / r;
                    (-d * d).exp() as f32
                };
                Placed::Round {
                    gx: cols
                        .clone()
                        .map(|i| factor(centre[0], radius[0], i))
                        .collect(),
                    gy: rows
                        .clone()
                        .map(|i| factor(centre[1], radius[1], i))
                        .collect(),
                    cols,
                    rows,
                }
            }
            Self::Tile(tile) => tile.place(centre, size),
        }
    }
}

/// Field amplitudes of a profile sampled every pixel around its centre: `data[j * side + i]`
/// is the amplitude at displacement `(i - half, j - half)` px from the centre.
#[derive(Debug, Clone)]
pub(crate) struct Tile {
    data: Vec<f32>,
    side: usize,
    half: usize,
}

impl Tile {
    fn new(
        profile: &BeamProfile,
        texture: &Texture,
        radius: [f64; 2],
        orientation: Orientation,
        seed: u64,
    ) -> Result<Self, String> {
        let field = ProfileField::new(profile)?;
        let size = radius[0].max(radius[1]);
        let half = (field.extent() * size).ceil().max(2.0) as usize;
        let side = 2 * half + 1;
        let speckle = match texture {
            Texture::Speckle { grain_px, .. } => Some(SpeckleTile::new(*grain_px, seed)),
            _ => None,
        };
        // Image displacement -> the beam's own frame: the inverse of the (orthogonal)
        // orientation, then per-axis scaling by the radius.
        let inverse = [
            [orientation[0][0], orientation[1][0]],
            [orientation[0][1], orientation[1][1]],
        ];
        let mut data = vec![0f32; side * side];
        let mut peak = 0f64;
        for j in 0..side {
            for i in 0..side {
                let d = [i as f64 - half as f64, j as f64 - half as f64];
                let own = [
                    inverse[0][0] * d[0] + inverse[0][1] * d[1],
                    inverse[1][0] * d[0] + inverse[1][1] * d[1],
                ];
                let mut amplitude = field.amplitude([own[0] / radius[0], own[1] / radius[1]]);
                let shade = texture_factor(texture, own, speckle.as_ref(), [i, j]);
                amplitude *= shade.max(0.0).sqrt();
                peak = peak.max(amplitude.abs());
                data[j * side + i] = amplitude as f32;
            }
        }
        if peak <= 0.0 {
            return Err("the beam profile has no light".into());
        }
        let scale = (1.0 / peak) as f32;
        data.iter_mut().for_each(|v| *v *= scale);
        Ok(Self { data, side, half }.trimmed())
    }

    /// The tile cut down to the square that holds all but a negligible rim.
    fn trimmed(self) -> Self {
        let floor = TILE_FLOOR.sqrt() as f32;
        let mut reach = 0usize;
        for j in 0..self.side {
            for i in 0..self.side {
                if self.data[j * self.side + i].abs() >= floor {
                    reach = reach.max(i.abs_diff(self.half)).max(j.abs_diff(self.half));
                }
            }
        }
        let half = (reach + 1).min(self.half);
        let side = 2 * half + 1;
        let start = self.half - half;
        let data = (0..side)
            .flat_map(|j| {
                let row = (start + j) * self.side + start;
                self.data[row..row + side].iter().copied()
            })
            .collect();
        Self { data, side, half }
    }

    fn place(&self, centre: [f64; 2], size: [usize; 2]) -> Placed<'_> {
        // Pixel x (centre x + 0.5) sits at tile coordinate x + base: its integer part moves
        // with x, its fraction is the same for the whole beam.
        let base = centre.map(|c| 0.5 - c + self.half as f64);
        let floor = base.map(f64::floor);
        let span = |axis: usize| {
            let lo = (-floor[axis]).max(0.0).min(size[axis] as f64) as usize;
            let hi = (self.side as f64 - 1.0 - floor[axis])
                .max(0.0)
                .min(size[axis] as f64) as usize;
            lo..hi.max(lo)
        };
        Placed::Tile {
            tile: self,
            cols: span(0),
            rows: span(1),
            origin: [floor[0] as isize, floor[1] as isize],
            fraction: [(base[0] - floor[0]) as f32, (base[1] - floor[1]) as f32],
        }
    }

    fn at(&self, i: isize, j: isize) -> f32 {
        if i < 0 || j < 0 || i as usize >= self.side || j as usize >= self.side {
            0.0
        } else {
            self.data[j as usize * self.side + i as usize]
        }
    }
}

/// A beam shape placed at one centre for one frame.
pub(crate) enum Placed<'a> {
    Round {
        cols: Range<usize>,
        rows: Range<usize>,
        gx: Vec<f32>,
        gy: Vec<f32>,
    },
    Tile {
        tile: &'a Tile,
        cols: Range<usize>,
        rows: Range<usize>,
        /// Tile index of pixel 0 (floor of the base), per axis.
        origin: [isize; 2],
        fraction: [f32; 2],
    },
}

impl Placed<'_> {
    /// The columns the beam reaches.
    pub(crate) fn cols(&self) -> Range<usize> {
        match self {
            Self::Round { cols, .. } | Self::Tile { cols, .. } => cols.clone(),
        }
    }

    /// The rows the beam reaches.
    pub(crate) fn rows(&self) -> Range<usize> {
        match self {
            Self::Round { rows, .. } | Self::Tile { rows, .. } => rows.clone(),
        }
    }

    /// Writes the field amplitude of row `y` times `scale` into `out[x]` for every column `x`
    /// the beam reaches (`out` spans the whole image row); other entries are left alone.
    /// Returns false, writing nothing, when the beam does not reach the row.
    pub(crate) fn amplitude_row(&self, y: usize, scale: f32, out: &mut [f32]) -> bool {
        let rows = self.rows();
        let cols = self.cols();
        if !rows.contains(&y) || cols.is_empty() {
            return false;
        }
        match self {
            Self::Round { gx, gy, .. } => {
                let a = scale * gy[y - rows.start];
                for (o, g) in out[cols].iter_mut().zip(gx) {
                    *o = a * g;
                }
            }
            Self::Tile {
                tile,
                origin,
                fraction,
                ..
            } => {
                let j = y as isize + origin[1];
                let [fx, fy] = *fraction;
                let (b0, b1) = (scale * (1.0 - fy), scale * fy);
                for x in cols {
                    let i = x as isize + origin[0];
                    let low = b0 * tile.at(i, j) + b1 * tile.at(i, j + 1);
                    let high = b0 * tile.at(i + 1, j) + b1 * tile.at(i + 1, j + 1);
                    out[x] = (1.0 - fx) * low + fx * high;
                }
            }
        }
        true
    }

    /// Adds the intensity of row `y` times `peak` into `out` (the whole image row).
    /// Returns whether the beam reaches the row.
    pub(crate) fn add_intensity_row(
        &self,
        y: usize,
        peak: f32,
        scratch: &mut [f32],
        out: &mut [f32],
    ) -> bool {
        if !self.amplitude_row(y, 1.0, scratch) {
            return false;
        }
        for x in self.cols() {
            out[x] += peak * scratch[x] * scratch[x];
        }
        true
    }
}

/// A profile as a function of the position in its own frame, in units of the radius.
enum ProfileField {
    Elliptical { axes: [f64; 2], angle: f64 },
    HermiteGauss { m: u32, n: u32, angle: f64 },
    Donut,
    TopHat { order: f64 },
    Image(Arc<ProfileImage>),
}

impl ProfileField {
    fn new(profile: &BeamProfile) -> Result<Self, String> {
        Ok(match profile {
            BeamProfile::Gaussian => Self::Elliptical {
                axes: [1.0, 1.0],
                angle: 0.0,
            },
            BeamProfile::Elliptical { axes, angle_deg } => Self::Elliptical {
                axes: *axes,
                angle: angle_deg.to_radians(),
            },
            BeamProfile::HermiteGauss { m, n, angle_deg } => Self::HermiteGauss {
                m: *m,
                n: *n,
                angle: angle_deg.to_radians(),
            },
            BeamProfile::Donut => Self::Donut,
            BeamProfile::TopHat { order } => Self::TopHat { order: *order },
            BeamProfile::Image { path, crop } => Self::Image(load_profile_image(path, *crop)?),
        })
    }

    /// How far the light reaches, in radii (generous; the tile is trimmed afterwards).
    fn extent(&self) -> f64 {
        match self {
            Self::Elliptical { axes, .. } => SPOT_EXTENT * axes[0].max(axes[1]),
            Self::HermiteGauss { m, n, .. } => SPOT_EXTENT + 1.5 * f64::from(m + n).sqrt(),
            Self::Donut => SPOT_EXTENT + 1.0,
            Self::TopHat { order } => 16f64.powf(1.0 / order) + 0.1,
            Self::Image(image) => image.extent,
        }
    }

    /// The field amplitude at `q` (radii, the profile's own frame before its angle).
    fn amplitude(&self, q: [f64; 2]) -> f64 {
        let turn = |angle: f64| {
            let (s, c) = angle.sin_cos();
            [c * q[0] + s * q[1], -s * q[0] + c * q[1]]
        };
        match self {
            Self::Elliptical { axes, angle } => {
                let [u, v] = turn(*angle);
                (-(u / axes[0]).powi(2) - (v / axes[1]).powi(2)).exp()
            }
            Self::HermiteGauss { m, n, angle } => {
                let [u, v] = turn(*angle);
                let s = std::f64::consts::SQRT_2;
                hermite(*m, s * u) * hermite(*n, s * v) * (-(u * u) - v * v).exp()
            }
            Self::Donut => {
                let r2 = q[0] * q[0] + q[1] * q[1];
                (2.0 * r2).sqrt() * (-r2).exp()
            }
            Self::TopHat { order } => {
                let r = q[0].hypot(q[1]);
                (-r.powf(*order)).exp()
            }
            Self::Image(image) => image.amplitude(q),
        }
    }
}

/// The physicists' Hermite polynomial H_n(x).
fn hermite(n: u32, x: f64) -> f64 {
    let (mut previous, mut current) = (1.0, 2.0 * x);
    if n == 0 {
        return previous;
    }
    for k in 1..n {
        let next = 2.0 * x * current - 2.0 * f64::from(k) * previous;
        previous = current;
        current = next;
    }
    current
}

/// The intensity factor of a texture at `own` (px, the beam's frame) and tile index `at`.
fn texture_factor(
    texture: &Texture,
    own: [f64; 2],
    speckle: Option<&SpeckleTile>,
    at: [usize; 2],
) -> f64 {
    match texture {
        Texture::None => 1.0,
        Texture::Etalon {
            contrast,
            period_px,
            angle_deg,
        } => {
            let (s, c) = angle_deg.to_radians().sin_cos();
            let along = c * own[0] + s * own[1];
            1.0 + contrast * (std::f64::consts::TAU * along / period_px).cos()
        }
        Texture::Speckle { contrast, .. } => {
            let grain = speckle.map_or(1.0, |tile| f64::from(tile.at(at[0], at[1])));
            1.0 - contrast + contrast * grain
        }
    }
}

/// A photographed beam, background-subtracted, with its intensity centroid and its
/// second-moment radius (in the photo's pixels).
#[derive(Debug)]
pub(crate) struct ProfileImage {
    width: usize,
    height: usize,
    /// Intensity, peak 1, row-major.
    intensity: Vec<f32>,
    centroid: [f64; 2],
    /// sqrt(2 (σx² + σy²)): the 1/e² radius of a round Gaussian with the same moments.
    radius: f64,
    /// Farthest corner from the centroid, in radii.
    extent: f64,
}

impl ProfileImage {
    /// Builds the profile from raw intensities (any scale): background = the median of the
    /// photo's border, subtracted and clipped at zero.
    fn from_intensities(width: usize, height: usize, raw: &[f64]) -> Result<Self, String> {
        if width < 4 || height < 4 {
            return Err(format!(
                "a beam photo needs at least 4 x 4 pixels, got {width} x {height}"
            ));
        }
        let mut border: Vec<f64> = (0..width)
            .flat_map(|x| [raw[x], raw[(height - 1) * width + x]])
            .chain((0..height).flat_map(|y| [raw[y * width], raw[y * width + width - 1]]))
            .collect();
        border.sort_by(f64::total_cmp);
        let background = border[border.len() / 2];
        let light: Vec<f64> = raw.iter().map(|v| (v - background).max(0.0)).collect();
        let (mut sum, mut sx, mut sy) = (0.0, 0.0, 0.0);
        for (i, v) in light.iter().enumerate() {
            sum += v;
            sx += v * ((i % width) as f64 + 0.5);
            sy += v * ((i / width) as f64 + 0.5);
        }
        if sum <= 0.0 {
            return Err("the beam photo shows no light above its border's level".into());
        }
        let centroid = [sx / sum, sy / sum];
        let second: f64 = light
            .iter()
            .enumerate()
            .map(|(i, v)| {
                let dx = (i % width) as f64 + 0.5 - centroid[0];
                let dy = (i / width) as f64 + 0.5 - centroid[1];
                v * (dx * dx + dy * dy)
            })
            .sum::<f64>()
            / sum;
        let radius = (2.0 * second).sqrt().max(0.5);
        let peak = light.iter().copied().fold(0.0, f64::max);
        let corners = [
            [0.0, 0.0],
            [width as f64, 0.0],
            [0.0, height as f64],
            [width as f64, height as f64],
        ];
        let extent = corners
            .iter()
            .map(|c| (c[0] - centroid[0]).hypot(c[1] - centroid[1]))
            .fold(0.0, f64::max)
            / radius;
        Ok(Self {
            width,
            height,
            intensity: light.iter().map(|v| (v / peak) as f32).collect(),
            centroid,
            radius,
            extent,
        })
    }

    /// The field amplitude at `q` radii from the centroid (bilinear in the photo).
    fn amplitude(&self, q: [f64; 2]) -> f64 {
        let x = self.centroid[0] + q[0] * self.radius - 0.5;
        let y = self.centroid[1] + q[1] * self.radius - 0.5;
        if x < 0.0 || y < 0.0 {
            return 0.0;
        }
        let (i, j) = (x.floor() as usize, y.floor() as usize);
        if i + 1 >= self.width || j + 1 >= self.height {
            return 0.0;
        }
        let (fx, fy) = (x - i as f64, y - j as f64);
        let at = |i: usize, j: usize| f64::from(self.intensity[j * self.width + i]);
        let v = (1.0 - fy) * ((1.0 - fx) * at(i, j) + fx * at(i + 1, j))
            + fy * ((1.0 - fx) * at(i, j + 1) + fx * at(i + 1, j + 1));
        v.sqrt()
    }
}

/// A beam photograph (8- or 16-bit grayscale, or colour converted to gray), or the part
/// `crop` (`[x, y, width, height]`, px) of it that holds the beam, once per path, part and
/// process.
pub(crate) fn load_profile_image(
    path: &Path,
    crop: Option<[u32; 4]>,
) -> Result<Arc<ProfileImage>, String> {
    type Key = (PathBuf, Option<[u32; 4]>);
    static CACHE: OnceLock<Mutex<HashMap<Key, Arc<ProfileImage>>>> = OnceLock::new();
    let cache = CACHE.get_or_init(Default::default);
    let key = (path.to_owned(), crop);
    if let Some(image) = cache.lock().unwrap_or_else(|e| e.into_inner()).get(&key) {
        return Ok(image.clone());
    }
    let photo = Photo::load(path)?;
    let part = match crop {
        Some(area) => photo
            .cropped(area)
            .map_err(|e| format!("beam photo {}: crop {e}", path.display()))?,
        None => (*photo).clone(),
    };
    let raw: Vec<f64> = part.levels.iter().map(|&v| f64::from(v)).collect();
    let image = Arc::new(
        ProfileImage::from_intensities(part.width, part.height, &raw)
            .map_err(|e| format!("beam photo {}: {e}", path.display()))?,
    );
    cache
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .insert(key, image.clone());
    Ok(image)
}

#[cfg(test)]
mod tests {
    use super::*;

    const IDENTITY: Orientation = [[1.0, 0.0], [0.0, 1.0]];

    /// Renders `shape` at `centre` on a w x h intensity image.
    fn intensity(shape: &BeamShape, centre: [f64; 2], w: usize, h: usize) -> Vec<f64> {
        let placed = shape.place(centre, [w, h]);
        let mut image = vec![0.0; w * h];
        let mut row = vec![0f32; w];
        for y in 0..h {
            if placed.amplitude_row(y, 1.0, &mut row) {
                for x in placed.cols() {
                    image[y * w + x] = f64::from(row[x]).powi(2);
                }
            }
        }
        image
    }

    fn moments(image: &[f64], w: usize) -> ([f64; 2], f64) {
        let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
        for (i, v) in image.iter().enumerate() {
            s += v;
            sx += v * ((i % w) as f64 + 0.5);
            sy += v * ((i / w) as f64 + 0.5);
        }
        let c = [sx / s, sy / s];
        let r2 = image
            .iter()
            .enumerate()
            .map(|(i, v)| {
                v * (((i % w) as f64 + 0.5 - c[0]).powi(2) + ((i / w) as f64 + 0.5 - c[1]).powi(2))
            })
            .sum::<f64>()
            / s;
        (c, (2.0 * r2).sqrt())
    }

    #[test]
    fn every_profile_is_centred_on_its_centroid_at_a_sub_pixel_position() {
        let profiles = [
            BeamProfile::Gaussian,
            BeamProfile::Elliptical {
                axes: [1.4, 0.6],
                angle_deg: 30.0,
            },
            BeamProfile::HermiteGauss {
                m: 0,
                n: 1,
                angle_deg: 10.0,
            },
            BeamProfile::Donut,
            BeamProfile::TopHat { order: 10.0 },
        ];
        for profile in profiles {
            let shape = BeamShape::Tile(
                Tile::new(&profile, &Texture::None, [30.0, 30.0], IDENTITY, 1).unwrap(),
            );
            let centre = [160.3, 121.7];
            let image = intensity(&shape, centre, 320, 240);
            let (c, _) = moments(&image, 320);
            assert!(
                (c[0] - centre[0]).abs() < 0.05 && (c[1] - centre[1]).abs() < 0.05,
                "{profile:?}: centroid {c:?}"
            );
            let peak = image.iter().copied().fold(0.0, f64::max);
            assert!((peak - 1.0).abs() < 0.05, "{profile:?}: peak {peak}");
        }
    }

    #[test]
    fn a_round_tile_matches_the_separable_gaussian() {
        let tile = BeamShape::Tile(
            Tile::new(
                &BeamProfile::Gaussian,
                &Texture::None,
                [25.0, 25.0],
                IDENTITY,
                1,
            )
            .unwrap(),
        );
        let round = BeamShape::Round {
            radius: [25.0, 25.0],
        };
        let a = intensity(&tile, [100.4, 80.9], 200, 160);
        let b = intensity(&round, [100.4, 80.9], 200, 160);
        let worst = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        assert!(worst < 2e-3, "{worst}");
        let (_, radius) = moments(&b, 200);
        assert!((radius - 25.0).abs() < 0.1, "{radius}");
    }

    #[test]
    fn hermite_gauss_lobes_have_opposite_field_signs() {
        let tile = Tile::new(
            &BeamProfile::HermiteGauss {
                m: 1,
                n: 0,
                angle_deg: 0.0,
            },
            &Texture::None,
            [20.0, 20.0],
            IDENTITY,
            1,
        )
        .unwrap();
        let h = tile.half as isize;
        let left = tile.at(h - 14, h);
        let right = tile.at(h + 14, h);
        assert!(left < -0.9 && right > 0.9, "{left} {right}");
        assert!(tile.at(h, h).abs() < 1e-6);
    }

    #[test]
    fn orientation_turns_and_mirrors_the_shape() {
        let profile = BeamProfile::Elliptical {
            axes: [2.0, 0.5],
            angle_deg: 0.0,
        };
        // Turned a quarter: the long axis runs along y.
        let quarter = [[0.0, -1.0], [1.0, 0.0]];
        let tile = Tile::new(&profile, &Texture::None, [10.0, 10.0], quarter, 1).unwrap();
        let h = tile.half as isize;
        assert!(tile.at(h, h + 15) > 0.1 && tile.at(h + 15, h) < 1e-3);
    }

    #[test]
    fn a_photo_is_centred_on_its_centroid_and_scaled_to_the_radius() {
        // An off-centre Gaussian spot of 1/e² radius 12 on a background of 100.
        let (w, h) = (80usize, 60usize);
        let raw: Vec<f64> = (0..w * h)
            .map(|i| {
                let dx = (i % w) as f64 + 0.5 - 30.0;
                let dy = (i / w) as f64 + 0.5 - 25.0;
                100.0 + 5000.0 * (-2.0 * (dx * dx + dy * dy) / 144.0).exp()
            })
            .collect();
        let photo = ProfileImage::from_intensities(w, h, &raw).unwrap();
        assert!((photo.centroid[0] - 30.0).abs() < 0.01 && (photo.centroid[1] - 25.0).abs() < 0.01);
        assert!((photo.radius - 12.0).abs() < 0.05, "{}", photo.radius);
        assert!((ProfileField::Image(Arc::new(photo)).amplitude([0.0, 0.0]) - 1.0).abs() < 1e-3);
        assert!(ProfileImage::from_intensities(w, h, &vec![3.0; w * h]).is_err());
    }

    #[test]
    fn etalon_texture_modulates_inside_the_beam() {
        let texture = Texture::Etalon {
            contrast: 0.5,
            period_px: 10.0,
            angle_deg: 0.0,
        };
        let tile = Tile::new(&BeamProfile::Gaussian, &texture, [30.0, 30.0], IDENTITY, 1).unwrap();
        let h = tile.half as isize;
        // Bright at s = 0, dark half a period along.
        let bright = tile.at(h, h).powi(2);
        let dark = tile.at(h + 5, h).powi(2);
        assert!(bright > 2.5 * dark, "{bright} {dark}");
    }
}
