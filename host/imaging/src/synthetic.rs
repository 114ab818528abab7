//! Synthetic camera frames for the detector's tests, written independently of the
//! simulator: beams of every kind a bench shows (round, elliptical and turned, two-lobed
//! Hermite-Gaussian modes, a doughnut, a flat top, beams with etalon fringes or speckle
//! inside, diffraction rings, saturated cores, beams cut by the border) with known centres,
//! and what surrounds them (stray spots, a sloping background, a smear column, hot pixels,
//! read noise).

use std::f64::consts::{PI, TAU};

use optalign_optics::Frame;

/// A frame under construction: light in gray levels per pixel.
pub struct Scene {
    width: usize,
    height: usize,
    light: Vec<f64>,
    noise: Option<(f64, u64)>,
}

/// SplitMix64: a small deterministic generator for noise and speckle.
struct Mix(u64);

impl Mix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }

    fn normal(&mut self) -> f64 {
        let (u1, u2) = (1.0 - self.unit(), self.unit());
        (-2.0 * u1.ln()).sqrt() * (TAU * u2).cos()
    }
}

impl Scene {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            light: vec![0.0; width * height],
            noise: None,
        }
    }

    /// Adds `f(dx, dy)` (dx, dy from `centre`, px) to every pixel.
    pub fn add(mut self, centre: [f64; 2], f: impl Fn(f64, f64) -> f64) -> Self {
        for y in 0..self.height {
            for x in 0..self.width {
                let (dx, dy) = (x as f64 + 0.5 - centre[0], y as f64 + 0.5 - centre[1]);
                self.light[y * self.width + x] += f(dx, dy);
            }
        }
        self
    }

    /// A uniform level plus a slope (gray levels per px in x and y from the centre).
    pub fn background(self, level: f64, slope: [f64; 2]) -> Self {
        let centre = [self.width as f64 / 2.0, self.height as f64 / 2.0];
        self.add(centre, move |dx, dy| level + slope[0] * dx + slope[1] * dy)
    }

    /// A round Gaussian of 1/e² radius `radius` and peak `peak`.
    pub fn gaussian(self, centre: [f64; 2], radius: f64, peak: f64) -> Self {
        self.add(centre, move |dx, dy| {
            peak * (-2.0 * (dx * dx + dy * dy) / (radius * radius)).exp()
        })
    }

    /// An elliptical Gaussian with 1/e² radii `radii`, its first axis turned `angle_deg`.
    pub fn elliptical(self, centre: [f64; 2], radii: [f64; 2], angle_deg: f64, peak: f64) -> Self {
        let (s, c) = angle_deg.to_radians().sin_cos();
        self.add(centre, move |dx, dy| {
            let (u, v) = (c * dx + s * dy, -s * dx + c * dy);
            peak * (-2.0 * ((u / radii[0]).powi(2) + (v / radii[1]).powi(2))).exp()
        })
    }

    /// A Hermite-Gaussian TEM_mn intensity of waist `w` (TEM01: lobes above and below).
    pub fn hermite_gauss(self, centre: [f64; 2], w: f64, m: u32, n: u32, peak: f64) -> Self {
        let hermite = |order: u32, t: f64| match order {
            0 => 1.0,
            1 => 2.0 * t,
            _ => 4.0 * t * t - 2.0,
        };
        // Peak of the normalised product, found numerically.
        let shape = move |dx: f64, dy: f64| {
            let (u, v) = (2f64.sqrt() * dx / w, 2f64.sqrt() * dy / w);
            (hermite(m, u) * hermite(n, v)).powi(2) * (-(u * u) - v * v).exp()
        };
        let top = (0..400)
            .flat_map(|i| (0..400).map(move |j| (i, j)))
            .map(|(i, j)| {
                shape(
                    (i as f64 - 200.0) * w / 100.0,
                    (j as f64 - 200.0) * w / 100.0,
                )
            })
            .fold(0.0, f64::max);
        self.add(centre, move |dx, dy| peak * shape(dx, dy) / top)
    }

    /// A doughnut (LG01) of waist `w`: a ring of radius w/√2.
    pub fn donut(self, centre: [f64; 2], w: f64, peak: f64) -> Self {
        self.add(centre, move |dx, dy| {
            let r2 = (dx * dx + dy * dy) / (w * w);
            peak * std::f64::consts::E * 2.0 * r2 * (-2.0 * r2).exp()
        })
    }

    /// A flat top of radius `radius` with a soft edge.
    pub fn top_hat(self, centre: [f64; 2], radius: f64, peak: f64) -> Self {
        self.add(centre, move |dx, dy| {
            peak * (-2.0 * ((dx * dx + dy * dy).sqrt() / radius).powi(12)).exp()
        })
    }

    /// Diffraction rings around a spot: rings of radius `spacing`, 2 `spacing`, ... at
    /// `level` falling off with the radius.
    pub fn rings(self, centre: [f64; 2], spacing: f64, level: f64) -> Self {
        self.add(centre, move |dx, dy| {
            let r = (dx * dx + dy * dy).sqrt() / spacing;
            if r < 0.5 {
                0.0
            } else {
                level * (PI * r).sin().powi(2) / (r * r)
            }
        })
    }

    /// Multiplies the light within `extent` px of `centre` by etalon fringes of `contrast`,
    /// `period` px, along `angle_deg`.
    pub fn etalon(mut self, centre: [f64; 2], contrast: f64, period: f64, angle_deg: f64) -> Self {
        let (s, c) = angle_deg.to_radians().sin_cos();
        for y in 0..self.height {
            for x in 0..self.width {
                let (dx, dy) = (x as f64 + 0.5 - centre[0], y as f64 + 0.5 - centre[1]);
                let along = c * dx + s * dy;
                self.light[y * self.width + x] *= 1.0 + contrast * (TAU * along / period).cos();
            }
        }
        self
    }

    /// Multiplies all light by a speckle-like pattern of `contrast` with grains of about
    /// `grain` px (a smoothed random field squared, mean 1).
    pub fn speckle(mut self, contrast: f64, grain: f64, seed: u64) -> Self {
        let (w, h) = (self.width, self.height);
        let mut rng = Mix(seed);
        let step = grain.max(1.0);
        let (gw, gh) = (
            (w as f64 / step).ceil() as usize + 2,
            (h as f64 / step).ceil() as usize + 2,
        );
        let re: Vec<f64> = (0..gw * gh).map(|_| rng.normal()).collect();
        let im: Vec<f64> = (0..gw * gh).map(|_| rng.normal()).collect();
        let sample = |field: &[f64], x: f64, y: f64| {
            let (i, j) = (x.floor() as usize, y.floor() as usize);
            let (fx, fy) = (x - i as f64, y - j as f64);
            let at = |i: usize, j: usize| field[j.min(gh - 1) * gw + i.min(gw - 1)];
            (1.0 - fy) * ((1.0 - fx) * at(i, j) + fx * at(i + 1, j))
                + fy * ((1.0 - fx) * at(i, j + 1) + fx * at(i + 1, j + 1))
        };
        for y in 0..h {
            for x in 0..w {
                let (u, v) = (x as f64 / step, y as f64 / step);
                let (a, b) = (sample(&re, u, v), sample(&im, u, v));
                // The intensity of a bilinear complex Gaussian field has a mean below 2.
                let grainy = (a * a + b * b) / 1.6;
                self.light[y * w + x] *= 1.0 - contrast + contrast * grainy;
            }
        }
        self
    }

    /// A bright vertical streak `width` px wide at column `x` through the whole frame.
    pub fn smear_column(mut self, x: usize, width: usize, level: f64) -> Self {
        for y in 0..self.height {
            for c in x..(x + width).min(self.width) {
                self.light[y * self.width + c] += level;
            }
        }
        self
    }

    /// `count` single hot pixels at `level` above the rest.
    pub fn hot_pixels(mut self, count: usize, level: f64, seed: u64) -> Self {
        let mut rng = Mix(seed);
        for _ in 0..count {
            let i = (rng.next() % self.light.len() as u64) as usize;
            self.light[i] += level;
        }
        self
    }

    /// Gaussian read noise of `std` gray levels (seeded), added when the frame is made.
    pub fn noise(mut self, std: f64, seed: u64) -> Self {
        self.noise = Some((std, seed));
        self
    }

    /// The 8-bit frame: light plus noise, rounded, clipped at 0 and 255.
    pub fn frame(&self) -> Frame {
        let mut rng = self.noise.map(|(_, seed)| Mix(seed));
        let std = self.noise.map_or(0.0, |(s, _)| s);
        let pixels = self
            .light
            .iter()
            .map(|&v| {
                let n = rng.as_mut().map_or(0.0, |r| std * r.normal());
                (v + n).round().clamp(0.0, 255.0) as u8
            })
            .collect();
        Frame::new(self.width as u32, self.height as u32, pixels).expect("sized to the frame")
    }
}
