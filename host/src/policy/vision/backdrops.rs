//! The light that stays put at each camera place (stray spots, ghosts): the agent throws the beam
//! clear and back, and the two frames give the place's [`Backdrop`], taken off later frames there.

use optalign_optics::Frame;

use super::model::{Vec2, distance};
use super::see::residue;
use super::tuning::{
    BACKDROPS_RESIDUE_SHARE, BESIDE_SHARE, CLEAR_RADII, COME_SHARE, HOLE_SHARE, KEPT_SHARE,
    OWN_LIGHT_NOISES,
};
use crate::imaging::{Backdrop, Beam, Picture, changes, find_beams};

/// One place's backdrop.
#[derive(Default)]
struct Place {
    /// The backdrop and its strongest feature.
    backdrop: Option<(Backdrop, Beam)>,
    /// A throw was made here during this visit.
    tried: bool,
    /// Borrowing another place's backdrop was tried here during this visit.
    borrow_tried: bool,
}

/// A throw under way: the place, the beam's spot and the picture before it.
pub struct Throw {
    place: usize,
    spot: Beam,
    before: Frame,
    /// The mount's command before the throw, to go back to.
    pub tilt: Vec2,
    /// The command of one throw, steps per axis, and how many were made.
    pub step: Vec2,
    pub made: usize,
    /// How far one throw moves the spot by the response, px.
    reach: f64,
}

/// What the frame after a throw showed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Thrown {
    /// The beam moved clear: the place has its backdrop.
    Learned,
    /// The beam moved, not yet clear of where it was: a further throw may clear it.
    Short,
    /// Nothing to learn from (the beam did not move, or the backdrop would not hold).
    Failed,
}

/// The backdrops of a task's camera places.
#[derive(Default)]
pub struct Backdrops {
    places: Vec<Place>,
}

impl Backdrops {
    pub fn new(places: usize) -> Self {
        Self {
            places: (0..places).map(|_| Place::default()).collect(),
        }
    }

    /// `frame` at `place` made ready, its backdrop taken off (one that leaves a hole is forgotten).
    pub fn picture(&mut self, place: usize, frame: &Frame) -> Picture {
        let picture = Picture::new(frame);
        let slot = &mut self.places[place];
        let Some(backdrop) = &slot.backdrop else {
            return self.borrow(place, frame, &picture).unwrap_or(picture);
        };
        taken_off(backdrop, frame, &picture).unwrap_or_else(|| {
            *slot = Place::default();
            picture
        })
    }

    /// Gives `place`, once per visit, the latest other backdrop with light beside the beam that
    /// leaves no hole in `frame` (light fixed to the camera shows alike everywhere).
    fn borrow(&mut self, place: usize, frame: &Frame, picture: &Picture) -> Option<Picture> {
        if std::mem::replace(&mut self.places[place].borrow_tried, true)
            || self.places.iter().all(|p| p.backdrop.is_none())
        {
            return None;
        }
        let brightest = find_beams(picture).first().map_or(0.0, |b| b.signal);
        let (lent, clean) = self
            .places
            .iter()
            .rev()
            .filter_map(|p| p.backdrop.as_ref())
            .filter(|(_, strongest)| strongest.signal >= BESIDE_SHARE * brightest)
            .find_map(|lent| taken_off(lent, frame, picture).map(|clean| (lent.clone(), clean)))?;
        self.places[place].backdrop = Some(lent);
        Some(clean)
    }

    pub fn learned(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.places.len()).filter(move |&i| self.places[i].backdrop.is_some())
    }

    /// The camera arrived at `place`: throwing and borrowing may be tried there again.
    pub fn arrived(&mut self, place: usize) {
        let p = &mut self.places[place];
        p.tried = false;
        p.borrow_tried = false;
    }

    /// Whether to throw at `place`: no backdrop or throw yet, and a strong feature beside `spot`.
    pub fn wanted(&self, place: usize, beams: &[Beam], spot: &Beam) -> bool {
        let p = &self.places[place];
        p.backdrop.is_none()
            && !p.tried
            && beams.iter().any(|b| {
                distance(b.centre, spot.centre) > 1.0 && b.signal >= BESIDE_SHARE * spot.signal
            })
    }

    /// Starts a throw of `step` (moving the spot `reach` px) from `before`, which shows `spot`.
    pub fn throw(
        &mut self,
        place: usize,
        before: &Frame,
        spot: Beam,
        tilt: Vec2,
        (step, reach): (Vec2, f64),
    ) -> Throw {
        self.places[place].tried = true;
        Throw {
            place,
            spot,
            before: before.clone(),
            tilt,
            step,
            made: 1,
            reach,
        }
    }

    /// Learns the place's backdrop from the frame `after` the throw: the frame before if the beam
    /// only came into view; once clear, both frames' darker cells, if removing them keeps the beam.
    pub fn learn(&mut self, throw: &Throw, after: &Frame) -> Thrown {
        let before = Picture::new(&throw.before);
        let after_picture = Picture::new(after);
        let moved = changes(&before, &after_picture);
        // Changes that count: a share of the strongest light, not flicker of a feature before.
        let features = find_beams(&before);
        let reference = features.first().map_or(throw.spot.signal, |f| f.signal);
        let notable = |blobs: &[Beam]| -> Vec<Beam> {
            blobs
                .iter()
                .filter(|c| {
                    c.signal >= COME_SHARE * reference
                        && !residue(c, &features, BACKDROPS_RESIDUE_SHARE)
                })
                .copied()
                .collect()
        };
        let gone = notable(&moved.vanished).first().copied();
        let come = notable(&moved.appeared);
        let noise = before.noise().max(after_picture.noise());
        let backdrop = match gone {
            None if !come.is_empty() => {
                Backdrop::from_pair(&throw.before, &throw.before, before.noise())
            }
            None => Backdrop::from_pair(&throw.before, after, noise),
            Some(gone) => {
                let radius = come
                    .iter()
                    .map(Beam::size)
                    .fold(gone.size().max(throw.spot.size()), f64::max);
                let thrown = throw.made as f64 * throw.reach;
                if thrown < CLEAR_RADII * radius
                    || come
                        .iter()
                        .any(|c| distance(c.centre, gone.centre) < CLEAR_RADII * radius)
                {
                    return Thrown::Short;
                }
                Backdrop::from_pair(&throw.before, after, noise).filter(|backdrop| {
                    backdrop
                        .removed_from(&throw.before, &before)
                        .is_some_and(|left| {
                            find_beams(&left).iter().any(|b| {
                                distance(b.centre, gone.centre) < gone.size()
                                    && b.signal >= KEPT_SHARE * gone.signal
                            })
                        })
                })
            }
        };
        let Some(backdrop) = backdrop else {
            return Thrown::Failed;
        };
        let light = backdrop.light_above(&after_picture);
        let Some(strongest) = strongest_with(&after_picture, light).filter(|s| s.signal > 0.0)
        else {
            return Thrown::Failed;
        };
        self.places[throw.place].backdrop = Some((backdrop, strongest));
        Thrown::Learned
    }
}

/// `frame` (made ready as `picture`) without `backdrop`; `None` when the sizes differ or it leaves
/// a hole: more light than the frame by a share of `strongest`'s (the frame's own light is zeroed,
/// lest it pull the hole's measuring window negative).
fn taken_off(
    (backdrop, strongest): &(Backdrop, Beam),
    frame: &Frame,
    picture: &Picture,
) -> Option<Picture> {
    let clean = backdrop.removed_from(frame, picture)?;
    let own = (OWN_LIGHT_NOISES * clean.noise()) as f32;
    let negated: Vec<f32> = clean
        .light()
        .iter()
        .map(|&v| if v > own { 0.0 } else { -v })
        .collect();
    let hole =
        strongest_with(&clean, negated).is_some_and(|h| h.signal >= HOLE_SHARE * strongest.signal);
    (!hole).then_some(clean)
}

/// The strongest feature of `picture` with its light replaced by `light`.
fn strongest_with(picture: &Picture, light: Vec<f32>) -> Option<Beam> {
    find_beams(&picture.with_light(light, picture.noise(), picture.noise_map().clone()))
        .first()
        .copied()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imaging::synthetic::Scene;

    /// A 640 x 480 frame: a beam of radius 100 px at `beam` (none when `None`) and a
    /// stationary stray spot of 80 px at `stray`.
    fn frame(beam: Option<[f64; 2]>, stray: [f64; 2], seed: u64) -> Frame {
        let scene = Scene::new(640, 480)
            .background(6.0, [0.0, 0.0])
            .gaussian(stray, 80.0, 176.0);
        match beam {
            Some(at) => scene.gaussian(at, 100.0, 220.0),
            None => scene,
        }
        .noise(2.5, seed)
        .frame()
    }

    const STRAY: [f64; 2] = [90.0, 346.0];

    /// A throw at place 0 from the beam at `from`.
    fn thrown(backdrops: &mut Backdrops, from: [f64; 2]) -> Throw {
        let before = frame(Some(from), STRAY, 1);
        let spot = *find_beams(&Picture::new(&before)).first().expect("a beam");
        backdrops.throw(0, &before, spot, [0.0; 2], ([0.0, 1000.0], 400.0))
    }

    #[test]
    fn a_throw_clear_of_the_beam_teaches_the_stray_light_and_it_is_taken_off() {
        let mut backdrops = Backdrops::new(2);
        let throw = thrown(&mut backdrops, [190.0, 200.0]);
        let other = [throw.spot, throw.spot.translated([250.0, 0.0])];
        assert!(backdrops.wanted(1, &other, &throw.spot));
        assert!(
            !backdrops.wanted(0, &other, &throw.spot),
            "tried on this visit"
        );
        let after = frame(Some([520.0, 150.0]), STRAY, 2);
        assert_eq!(backdrops.learn(&throw, &after), Thrown::Learned);
        assert_eq!(backdrops.learned().collect::<Vec<_>>(), vec![0]);
        // Touching the stray, the beam is found alone and where it is.
        let clean = backdrops.picture(0, &frame(Some([200.0, 230.0]), STRAY, 3));
        let beams = find_beams(&clean);
        assert_eq!(beams.len(), 1, "{beams:?}");
        assert!(distance(beams[0].centre, [200.0, 230.0]) < 1.0, "{beams:?}");
    }

    #[test]
    fn another_place_borrows_a_backdrop_only_where_its_light_shows_the_same() {
        let mut backdrops = Backdrops::new(3);
        let throw = thrown(&mut backdrops, [190.0, 200.0]);
        assert_eq!(
            backdrops.learn(&throw, &frame(Some([520.0, 150.0]), STRAY, 2)),
            Thrown::Learned
        );
        // Place 1 shows the stray light where place 0 did (fixed to the camera): it
        // borrows the backdrop, and the beam touching the stray is found alone.
        let clean = backdrops.picture(1, &frame(Some([200.0, 230.0]), STRAY, 3));
        let beams = find_beams(&clean);
        assert_eq!(beams.len(), 1, "{beams:?}");
        assert!(distance(beams[0].centre, [200.0, 230.0]) < 1.0, "{beams:?}");
        assert_eq!(backdrops.learned().collect::<Vec<_>>(), vec![0, 1]);
        // Place 2 shows its own stray light elsewhere: nothing is borrowed, nothing taken off.
        let elsewhere = frame(Some([400.0, 150.0]), [240.0, 346.0], 4);
        assert_eq!(
            backdrops.picture(2, &elsewhere).light(),
            Picture::new(&elsewhere).light()
        );
        assert_eq!(backdrops.learned().collect::<Vec<_>>(), vec![0, 1]);
    }

    #[test]
    fn a_throw_into_the_dark_or_short_of_clear_is_told_apart() {
        let mut backdrops = Backdrops::new(1);
        let throw = thrown(&mut backdrops, [190.0, 200.0]);
        let short = frame(Some([290.0, 200.0]), STRAY, 4);
        assert_eq!(backdrops.learn(&throw, &short), Thrown::Short);
        let dark = frame(None, STRAY, 5);
        assert_eq!(backdrops.learn(&throw, &dark), Thrown::Learned);
    }

    #[test]
    fn a_throw_shorter_than_the_beam_is_short_though_its_spot_looked_small() {
        // The spot thrown was seen as a fragment a tenth of the beam, and the throw went
        // 120 px: the beam (radius about 100 px) is not clear of itself, wherever it shows.
        let mut backdrops = Backdrops::new(1);
        let before = frame(Some([190.0, 200.0]), STRAY, 1);
        let mut spot = *find_beams(&Picture::new(&before)).first().expect("a beam");
        spot.radii = spot.radii.map(|r| r / 10.0);
        let throw = backdrops.throw(0, &before, spot, [0.0; 2], ([0.0, 300.0], 120.0));
        let dark = frame(None, STRAY, 5);
        assert_eq!(backdrops.learn(&throw, &dark), Thrown::Short);
        assert_eq!(backdrops.learned().count(), 0);
    }

    #[test]
    fn a_backdrop_whose_light_moved_is_forgotten() {
        let mut backdrops = Backdrops::new(1);
        let throw = thrown(&mut backdrops, [190.0, 200.0]);
        let dark = frame(None, STRAY, 5);
        assert_eq!(backdrops.learn(&throw, &dark), Thrown::Learned);
        // The camera sits differently: the stray light shows 150 px away.
        let moved = backdrops.picture(0, &frame(Some([400.0, 150.0]), [240.0, 346.0], 6));
        assert_eq!(backdrops.learned().count(), 0);
        assert_eq!(find_beams(&moved).len(), 2);
    }
}
