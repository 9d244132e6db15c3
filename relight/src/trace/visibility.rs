//! Shadow-ray visibility of every light from every row, one bit per pair, cached
//! between iterations: a light is re-traced only when it moved more than a tolerance
//! since its last trace (colour and intensity phases never re-trace).
//!
//! A bit is set when the light is in front of the row (`n . d > 0`) and the segment from
//! `x + n shadow_offset` to the light meets no occluder farther than the inhibit radius from
//! its start ([`crate::rows::Sampling`]). `n` is the row's normal turned towards the
//! light ([`Rows::facing`]): a two-sided row sees lights on both sides, each from the
//! side it lies on.

use glam::Vec3;
use rayon::prelude::*;

use crate::rows::{Rows, Sampling};
use crate::trace::bvh::{Bvh, Occluder, EDGE_SLACK};
use crate::trace::pieces::Shadow;
use crate::trace::wide::PACKET;


#[derive(Debug, Clone, Default)]
pub struct Visibility {
    /// Bits per light, `words_per_light` u32 words each. Replaced through
    /// [`Visibility::update`], [`Visibility::set_traced`] or [`Visibility::push_traced`],
    /// which keep `units` in step; shared by clones (the fits save and restore the whole
    /// cache at every try: hundreds of lights' bits, megabytes a copy).
    pub bits: Vec<Bits>,
    /// Per light: the unit factors cached for its bits ([`UnitSlot`]); shared by clones,
    /// replaced (never changed in place) when the light's bits change.
    units: Vec<std::sync::Arc<UnitSlot>>,
    /// Light position at its last trace.
    pub traced_at: Vec<Vec3>,
    /// The reach it was traced to (rows farther away have their bit clear).
    pub traced_reach: Vec<f32>,
    /// The sun's bits and the direction they were traced for (see [`sun_visible_from`]).
    pub sun: Option<(Vec3, Vec<u32>)>,
    /// Rays traced so far (all lights, all updates).
    pub rays: u64,
}

/// What an evaluation reads of a [`Visibility`] (each light's bits, the sun's), held so
/// that a later state can be asked whether it is the same ([`Visibility::is`]).
#[derive(Debug, Clone)]
pub struct Snapshot {
    /// Held, so that no other light's bits can take their allocation while this lives.
    bits: Vec<Bits>,
    sun: Option<(Vec3, Vec<u32>)>,
}

impl Visibility {
    /// The state an evaluation reads now.
    pub fn snapshot(&self) -> Snapshot {
        Snapshot { bits: self.bits.clone(), sun: self.sun.clone() }
    }

    /// Whether every light's bits and the sun's are those of `s`: the same lights' bits by
    /// identity (never changed in place, replaced whole), the sun's by value. Where it
    /// holds, an evaluation of one model gives what it gave at `s`, to the bit.
    pub fn is(&self, s: &Snapshot) -> bool {
        self.bits.len() == s.bits.len() && self.bits.iter().zip(&s.bits).all(|(a, b)| std::sync::Arc::ptr_eq(a, b)) && self.sun.as_ref().map(|(d, b)| (d.to_array().map(f32::to_bits), b)) == s.sun.as_ref().map(|(d, b)| (d.to_array().map(f32::to_bits), b))
    }

    #[inline]
    pub fn visible(&self, light: usize, vertex: usize) -> bool {
        self.bits[light][vertex >> 5] >> (vertex & 31) & 1 == 1
    }

    /// Calls `f(row)` for every row in `rows` that light `light` reaches, in ascending
    /// order, 32 rows per word: a word with no bit set costs one test (a light whose
    /// reach or shadows leave most rows dark is skipped over them at once).
    #[inline]
    pub fn for_each_visible(&self, light: usize, rows: std::ops::Range<usize>, f: impl FnMut(usize)) {
        each_set_bit(&self.bits[light], rows, f);
    }

    /// [`Visibility::for_each_visible`] without the words whose rows all lie farther than
    /// `sqrt(dist2)` meters from `at` ([`WordBoxes`] of the rows): for the rows a light
    /// reaches within the distance its falloff cut leaves it.
    #[inline]
    pub fn for_each_visible_within(&self, light: usize, rows: std::ops::Range<usize>, boxes: &WordBoxes, at: Vec3, dist2: f32, f: impl FnMut(usize)) {
        each_set_bit_where(&self.bits[light], rows, |w, _| !boxes.beyond(w, at, dist2), f);
    }

    /// Whether the sun (as last traced) reaches `vertex`.
    #[inline]
    pub fn sun_visible(&self, vertex: usize) -> bool {
        self.sun.as_ref().is_some_and(|(_, b)| b[vertex >> 5] >> (vertex & 31) & 1 == 1)
    }

    /// Brings the sun's bits up to date: re-traced (with `trace`) when the direction turned
    /// by more than `tolerance` radians since the last trace; dropped without a sun. A
    /// failed trace leaves the cache as it was.
    pub fn update_sun(&mut self, to_sun: Option<Vec3>, tolerance: f32, n_vertices: usize, trace: &mut dyn FnMut(Vec3) -> crate::error::Result<Vec<u32>>) -> crate::error::Result<()> {
        let Some(dir) = to_sun else {
            self.sun = None;
            return Ok(());
        };
        let fresh = self.sun.as_ref().is_some_and(|(d, _)| d.dot(dir).clamp(-1.0, 1.0).acos() <= tolerance);
        if !fresh {
            self.sun = Some((dir, trace(dir)?));
            self.rays += n_vertices as u64;
        }
        Ok(())
    }

    /// Brings the cache up to date with `lights` (position, brightest channel in W/sr:
    /// [`crate::model::Light::source`]): traces (with `trace`, a batch of light
    /// positions and reaches to bit vectors) new lights, lights that moved more than
    /// `tolerance` meters and lights whose reach ([`reach`] under `sampling`) outgrew the
    /// one they were traced to; drops lights beyond `lights.len()`. Returns how many lights
    /// were traced.
    pub fn update(&mut self, lights: &[(Vec3, f32)], tolerance: f32, sampling: &Sampling, n_vertices: usize, trace: &mut dyn FnMut(&[(Vec3, f32)]) -> crate::error::Result<Vec<Vec<u32>>>) -> crate::error::Result<usize> {
        self.units.resize_with(self.bits.len(), Default::default);
        self.bits.truncate(lights.len());
        self.traced_at.truncate(lights.len());
        self.traced_reach.truncate(lights.len());
        self.units.truncate(lights.len());
        let stale: Vec<usize> = (0..lights.len())
            .filter(|&j| j >= self.bits.len() || (self.traced_at[j] - lights[j].0).length() > tolerance || reach(lights[j].1, sampling, 1.0) > self.traced_reach[j])
            .collect();
        if stale.is_empty() {
            return Ok(0);
        }
        // Traced with room to grow, so that a light brightening a little is not re-traced.
        let batch: Vec<(Vec3, f32)> = stale.iter().map(|&j| (lights[j].0, reach(lights[j].1, sampling, REACH_MARGIN))).collect();
        let traced = trace(&batch)?;
        self.rays += (n_vertices * stale.len()) as u64;
        for ((&j, words), &(_, r)) in stale.iter().zip(traced).zip(&batch) {
            if j < self.bits.len() {
                self.set_traced(j, words, lights[j].0, r);
            } else {
                self.push_traced(words, lights[j].0, r);
            }
        }
        Ok(stale.len())
    }

    /// Light `j`'s bits as traced from `at` to `reach` (its cached unit factors dropped).
    pub fn set_traced(&mut self, j: usize, bits: Vec<u32>, at: Vec3, reach: f32) {
        self.units.resize_with(self.bits.len(), Default::default);
        self.bits[j] = Bits::new(bits);
        self.traced_at[j] = at;
        self.traced_reach[j] = reach;
        self.units[j] = Default::default();
    }

    /// A further light's bits, as traced from `at` to `reach`.
    pub fn push_traced(&mut self, bits: Vec<u32>, at: Vec3, reach: f32) {
        self.units.resize_with(self.bits.len(), Default::default);
        self.bits.push(Bits::new(bits));
        self.traced_at.push(at);
        self.traced_reach.push(reach);
        self.units.push(Default::default());
    }

    /// Light `j`'s cache of unit factors, where it has one (see [`UnitSlot`]).
    pub fn unit_slot(&self, j: usize) -> Option<&UnitSlot> {
        (self.units.len() == self.bits.len()).then(|| self.units.get(j)).flatten().map(|s| &**s)
    }

    /// [`Visibility::for_each_visible`] with each row's entry of `list`, light `light`'s
    /// [`UnitList`] for its current bits: `f(row, value)`.
    #[inline]
    pub fn for_each_visible_with(&self, light: usize, rows: std::ops::Range<usize>, list: &UnitList, f: impl FnMut(usize, f32)) {
        self.for_each_visible_with_where(light, rows, list, |_, _| true, f)
    }

    /// [`Visibility::for_each_visible_with`] within a distance, as
    /// [`Visibility::for_each_visible_within`].
    #[inline]
    pub fn for_each_visible_with_within(&self, light: usize, rows: std::ops::Range<usize>, list: &UnitList, boxes: &WordBoxes, at: Vec3, dist2: f32, f: impl FnMut(usize, f32)) {
        self.for_each_visible_with_where(light, rows, list, |w, _| !boxes.beyond(w, at, dist2), f)
    }

    /// [`Visibility::for_each_visible_with`] over the words `keep(word index, bits)`
    /// keeps; the list's index steps over the others' entries.
    #[inline]
    fn for_each_visible_with_where(&self, light: usize, rows: std::ops::Range<usize>, list: &UnitList, mut keep: impl FnMut(usize, u32) -> bool, mut f: impl FnMut(usize, f32)) {
        let bits = &self.bits[light];
        if rows.is_empty() {
            return;
        }
        // The list's index of the first row at or after `rows.start`: the set bits before
        // it, counted from the start of its stretch.
        let w0 = rows.start >> 5;
        let first = (w0 / UNIT_STRETCH_WORDS) * UNIT_STRETCH_WORDS;
        let mut k = list.stretch_start.get(w0 / UNIT_STRETCH_WORDS).copied().unwrap_or(0) as usize;
        k += bits[first.min(bits.len())..w0.min(bits.len())].iter().map(|w| w.count_ones() as usize).sum::<usize>();
        k += bits.get(w0).map_or(0, |w| (w & !(u32::MAX << (rows.start & 31))).count_ones() as usize);
        let k = std::cell::Cell::new(k);
        each_set_bit_where(
            bits,
            rows,
            |w, word| {
                let kept = keep(w, word);
                if !kept {
                    k.set(k.get() + word.count_ones() as usize);
                }
                kept
            },
            |i| {
                f(i, list.values[k.get()]);
                k.set(k.get() + 1);
            },
        );
    }

    /// The cache of the lights `js` only, in that order (the sun's bits with them).
    pub fn select(&self, js: &[usize]) -> Visibility {
        Visibility {
            bits: js.iter().map(|&j| self.bits[j].clone()).collect(),
            traced_at: js.iter().map(|&j| self.traced_at[j]).collect(),
            traced_reach: js.iter().map(|&j| self.traced_reach[j]).collect(),
            units: if self.units.len() == self.bits.len() { js.iter().map(|&j| self.units[j].clone()).collect() } else { Vec::new() },
            sun: self.sun.clone(),
            rays: 0,
        }
    }

    /// The rows that any of the lights `js` reaches as last traced, ascending.
    pub fn reached_rows(&self, js: &[usize]) -> Vec<usize> {
        let words = js.iter().map(|&j| self.bits[j].len()).max().unwrap_or(0);
        let mut union = vec![0u32; words];
        for &j in js {
            union.iter_mut().zip(self.bits[j].iter()).for_each(|(u, &w)| *u |= w);
        }
        let mut rows = Vec::new();
        each_set_bit(&union, 0..32 * words, |i| rows.push(i));
        rows
    }

    /// The cache of the lights `js` (in that order) and the sun over the rows `keep` only:
    /// row `k` of the result is row `keep[k]` of this one. The traced positions and reaches
    /// stay; the cached unit factors are dropped.
    pub fn select_rows(&self, js: &[usize], keep: &[usize]) -> Visibility {
        let pick = |bits: &[u32]| -> Vec<u32> {
            let mut out = vec![0u32; keep.len().div_ceil(32)];
            for (k, &i) in keep.iter().enumerate() {
                if bits.get(i >> 5).is_some_and(|w| w >> (i & 31) & 1 == 1) {
                    out[k >> 5] |= 1 << (k & 31);
                }
            }
            out
        };
        Visibility {
            bits: js.iter().map(|&j| Bits::new(pick(&self.bits[j]))).collect(),
            traced_at: js.iter().map(|&j| self.traced_at[j]).collect(),
            traced_reach: js.iter().map(|&j| self.traced_reach[j]).collect(),
            units: Vec::new(),
            sun: self.sun.as_ref().map(|(d, b)| (*d, pick(b))),
            rays: 0,
        }
    }

    /// Puts back what [`Visibility::select`] took out as `part` (its lights `js`, the sun),
    /// with the rays it traced since.
    pub fn put_back(&mut self, js: &[usize], part: Visibility) {
        let units = if part.units.len() == part.bits.len() { part.units.into_iter().map(Some).collect() } else { vec![None; js.len()] };
        self.units.resize_with(self.bits.len(), Default::default);
        for (((&j, bits), (at, reach)), unit) in js.iter().zip(part.bits).zip(part.traced_at.into_iter().zip(part.traced_reach)).zip(units) {
            self.bits[j] = bits;
            self.traced_at[j] = at;
            self.traced_reach[j] = reach;
            self.units[j] = unit.unwrap_or_default();
        }
        self.sun = part.sun;
        self.rays += part.rays;
    }

    /// Replaces the cache of light `j` (used when lights are reordered or removed).
    pub fn remove(&mut self, j: usize) {
        self.units.resize_with(self.bits.len(), Default::default);
        self.bits.remove(j);
        self.traced_at.remove(j);
        self.traced_reach.remove(j);
        self.units.remove(j);
    }
}

/// One light's visibility bits (32 rows a word), shared by the clones of a
/// [`Visibility`]: never changed in place, replaced whole.
pub type Bits = std::sync::Arc<Vec<u32>>;

/// Calls `f(row)` for every set bit of `bits` in `rows`, in ascending order, 32 rows per
/// word (a word with no bit set costs one test).
#[inline]
pub fn each_set_bit(bits: &[u32], rows: std::ops::Range<usize>, f: impl FnMut(usize)) {
    each_set_bit_where(bits, rows, |_, _| true, f)
}

/// [`each_set_bit`] over the words with a bit set in `rows` that `keep(word index, the
/// word's bits in rows)` keeps.
#[inline]
pub fn each_set_bit_where(bits: &[u32], rows: std::ops::Range<usize>, mut keep: impl FnMut(usize, u32) -> bool, mut f: impl FnMut(usize)) {
    if rows.is_empty() {
        return;
    }
    let (w0, w1) = (rows.start >> 5, (rows.end + 31) >> 5);
    for w in w0..w1.min(bits.len()) {
        let mut word = bits[w];
        if w == w0 {
            word &= u32::MAX << (rows.start & 31);
        }
        if w + 1 == w1 && rows.end & 31 != 0 {
            word &= (1u32 << (rows.end & 31)) - 1;
        }
        if word == 0 || !keep(w, word) {
            continue;
        }
        while word != 0 {
            let i = (w << 5) | word.trailing_zeros() as usize;
            word &= word - 1;
            f(i);
        }
    }
}

/// The bounding box of each visibility word's 32 rows (the last word's as far as there
/// are rows), min and max corner: a word whose box lies beyond a distance from a point
/// has all its rows beyond it. Built from rows that its holder borrows for as long as it
/// keeps the boxes (the CPU backend, a fit), so that the rows cannot move under them.
#[derive(Debug, Clone, Default)]
pub struct WordBoxes(Vec<[Vec3; 2]>);

impl WordBoxes {
    pub fn of(rows: &Rows) -> WordBoxes {
        WordBoxes(rows.pos.par_chunks(32).map(|c| c.iter().fold([Vec3::INFINITY, Vec3::NEG_INFINITY], |[lo, hi], &p| [lo.min(p), hi.max(p)])).collect())
    }

    /// Whether every row of word `w` lies farther than `sqrt(dist2)` from `at` (false for
    /// a word it has no box for, and wherever the test meets a NaN).
    #[inline]
    pub fn beyond(&self, w: usize, at: Vec3, dist2: f32) -> bool {
        match self.0.get(w) {
            Some(&[lo, hi]) => (at.max(lo).min(hi) - at).length_squared() > dist2,
            None => false,
        }
    }
}

/// Words of bits per stretch of a [`UnitList`]'s index (1024 rows).
pub const UNIT_STRETCH_WORDS: usize = 32;

/// One light's unit factor at each row its bits reach, in row order (for
/// [`crate::model::lights`]: its `g` before the falloff cut, which depends on the
/// intensity), computed for one geometry of the light (its [`UnitKey`]).
#[derive(Debug, Default)]
pub struct UnitList {
    /// One per set bit, in row order.
    pub values: Vec<f32>,
    /// Per stretch of [`UNIT_STRETCH_WORDS`] words: the set bits before it.
    pub stretch_start: Vec<u32>,
}

/// What a light's unit factors depend on besides its bits: its position and spot, and
/// where it was traced from, to what reach, as exact bits.
pub type UnitKey = [u32; 12];

/// A light's cache of unit factors: filled the second time in a row that the same geometry
/// asks (a light the phases move asks with a new one each time and never fills it; the
/// linear fits of pruning, merging and the terms' decisions, over lights that stand still,
/// ask again and again). Shared by the clones of a [`Visibility`], which is sound because
/// the slot is replaced whenever the light's bits are.
#[derive(Debug, Default)]
pub struct UnitSlot {
    state: std::sync::Mutex<(Option<UnitKey>, Option<(UnitKey, std::sync::Arc<UnitList>)>)>,
}

impl UnitSlot {
    /// The list for `key`, if cached; else `Err(again)`: whether the same key was asked
    /// just before (then the caller may build it and [`UnitSlot::store`] it).
    pub fn lookup(&self, key: &UnitKey) -> Result<std::sync::Arc<UnitList>, bool> {
        let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((k, list)) = &st.1 {
            if k == key {
                return Ok(list.clone());
            }
        }
        let again = st.0.as_ref() == Some(key);
        st.0 = Some(*key);
        Err(again)
    }

    /// Keeps `list` as the cache for `key`.
    pub fn store(&self, key: UnitKey, list: std::sync::Arc<UnitList>) {
        let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        st.1 = Some((key, list));
    }
}

/// The ray towards a sun from a row, `(origin, segment across the scene, t_min)`: none
/// when the sun is behind the row, or exactly along the wall a row on its plane meets.
fn sun_ray(bvh: &Bvh, x: Vec3, n: Vec3, to_sun: Vec3, s: &Sampling, ahead: crate::rows::SolidAhead) -> Option<(Vec3, Vec3, f32)> {
    if !(n.dot(to_sun) > 0.0) || (s.on_epsilon > 0.0 && ahead.along(to_sun)) {
        return None;
    }
    let reach = bvh.reach();
    Some((x + n * s.shadow_offset, to_sun * reach, s.inhibit / reach))
}

/// Sun visibility: the sun (direction `to_sun`, unit) is in front of the row and the ray
/// from `x + n * offset` towards it first meets a sky surface (`sky[t]` for mesh triangle
/// `t`), as q3map2 decides (a Quake map is sealed: sunlight comes in through sky
/// surfaces only; a ray that leaves through a gap of the converted mesh brings nothing).
/// A scene without sky surfaces (a glTF from elsewhere) is open: a ray that escapes sees
/// the sun. From a point on a wall's plane with its brush on Quake's positive side, a sun
/// exactly along the wall is not seen ([`crate::rows::SolidAhead::along`]).
pub fn sun_visible_from(bvh: &Bvh, x: Vec3, n: Vec3, to_sun: Vec3, s: &Sampling, sky: &[bool], ahead: crate::rows::SolidAhead) -> bool {
    let Some((o, d, t_min)) = sun_ray(bvh, x, n, to_sun, s, ahead) else { return false };
    match bvh.first_hit_after(o, d, t_min, 1.0) {
        None => !sky.iter().any(|&k| k),
        Some((_, t)) => sky.get(t as usize).copied().unwrap_or(false),
    }
}

/// Whether one of the sky light's suns, towards `to_sun`, lights `x` (normal `n`), as
/// q3map2 decides it for its suns: the ray crosses a sky surface and no opaque surface
/// anywhere along the scene (q3map2 traces the whole way, not to the first hit), and a
/// ray along an opaque face's edge is stopped by it (the shadow walk's slack,
/// [`crate::trace::bvh::EDGE_SLACK`]; q3map2's own is 1% of its trace pieces). Its sky
/// light is many such suns, and the map's edges are where the rays graze: the floor
/// under a sky opening, lit by the straight-up sun along the opening's walls (fixture
/// `skylight_bright`: 0.0388 -> 0.0250).
///
/// `open`: the scene has no sky surface (a glTF from elsewhere): a ray that nothing
/// stops sees the sun. The caller finds it once, not per ray.
///
/// `hints`: pieces that stopped earlier rays, tried first (the row's previous sun, the
/// previous row's ray to this sun; q3map2's pieces only, see
/// [`crate::trace::pieces::Shadow::occluded_hinted`]); `crossed`: the sky triangle the
/// previous row's ray to this sun crossed, tried first ([`Tree::hits_where_hinted`](crate::trace::tree::Tree::hits_where_hinted)).
/// Neither changes the answer.
#[allow(clippy::too_many_arguments)]
pub fn sky_visible_from(bvh: &Bvh, x: Vec3, n: Vec3, to_sun: Vec3, s: &Sampling, sky: &[bool], open: bool, ahead: crate::rows::SolidAhead, hints: &mut [&mut Occluder], crossed: &mut Occluder) -> bool {
    let Some((o, d, t_min)) = sun_ray(bvh, x, n, to_sun, s, ahead) else { return false };
    let is_sky = |t: u32| sky.get(t as usize).copied().unwrap_or(false);
    // The sky first: most suns of a row indoors meet none, and then nothing else is traced.
    let mut blocked = || match &bvh.shadow {
        Some(pieces) => pieces.occluded_hinted(o, d, t_min, 1.0, hints),
        None => bvh.hits_where(o, d, t_min, 1.0, EDGE_SLACK, |t| !is_sky(t)),
    };
    (open || bvh.hits_where_hinted(o, d, t_min, 1.0, 0.0, is_sky, &mut [crossed])) && !blocked()
}

/// Rows per block of [`by_neighbour_blocks`].
pub const HINT_ROWS: usize = 32;

/// Every row `i < n`'s state (from `row`) after `f(i, k, state, hint)` over every source
/// `k < sources` in order: rayon over blocks of [`HINT_ROWS`] neighbouring rows, and within
/// a block source by source, each source's rays from the block's rows one after another.
/// Those rays are near-identical, so the walks of one source find the tree's nodes in the
/// cache where the previous row's walk left them; and each source's `hint` (from `hint`,
/// one per block and source) is handed from row to row, so that a row's ray to a source
/// tries first what stopped the previous row's ray to it (the surface lights' and the
/// sky's bases; the answers are the walks'). Each row still sees its sources in order, so
/// what it sums comes out bit for bit as a row-by-row loop would sum it.
pub fn by_neighbour_blocks<S: Send, H>(n: usize, sources: usize, row: impl Fn(usize) -> S + Sync, hint: impl Fn() -> H + Sync, f: impl Fn(usize, usize, &mut S, &mut H) + Sync) -> Vec<S> {
    by_neighbour_block_sources(n, sources, row, |rows, k, states| {
        let mut h = hint();
        for (i, state) in rows.zip(states.iter_mut()) {
            f(i, k, state, &mut h);
        }
    })
}

/// [`by_neighbour_blocks`] handing `f` a whole block's rows for one source at a time:
/// `f(rows, source, their states)`, sources in order; for a block's rays to one source
/// taken together ([`visible_together`]).
pub fn by_neighbour_block_sources<S: Send>(n: usize, sources: usize, row: impl Fn(usize) -> S + Sync, f: impl Fn(std::ops::Range<usize>, usize, &mut [S]) + Sync) -> Vec<S> {
    let blocks: Vec<Vec<S>> = (0..n.div_ceil(HINT_ROWS))
        .into_par_iter()
        .map(|b| {
            let rows = b * HINT_ROWS..((b + 1) * HINT_ROWS).min(n);
            let mut states: Vec<S> = rows.clone().map(&row).collect();
            for k in 0..sources {
                f(rows.clone(), k, &mut states);
            }
            states
        })
        .collect();
    blocks.into_iter().flatten().collect()
}

/// One shadow ray of [`visible_together`]: from `x` (normal `n`, turned as the caller's
/// row faces) to `target`.
#[derive(Debug, Clone, Copy)]
pub struct ShadowRay {
    pub x: Vec3,
    pub n: Vec3,
    pub target: Vec3,
}

/// [`visible_hinted`] for several rays in order, each trying its own hint (`own[r]`)
/// and then `shared` (the previous ray's, handed on): `visible[r]` is ray `r`'s answer.
/// Through q3map2's pieces the rays the hints do not stop are walked [`PACKET`] at a time
/// ([`Shadow::occluders_packet`]); a walk's piece is remembered in the ray's hint and in
/// `shared`, as [`visible_hinted`] remembers it. The answers are the walks'; only which
/// piece is remembered can differ from one call per ray.
pub fn visible_together(bvh: &Bvh, rays: &[ShadowRay], s: &Sampling, own: &mut [Occluder], shared: &mut Occluder, visible: &mut [bool]) {
    let Some(pieces) = &bvh.shadow else {
        for (r, ray) in rays.iter().enumerate() {
            visible[r] = visible_hinted(bvh, ray.x, ray.n, ray.target, s, &mut [&mut own[r], shared]);
        }
        return;
    };
    let mut waiting = Waiting::default();
    for (r, ray) in rays.iter().enumerate() {
        match shadow_segment(ray.x, ray.n, ray.target, s) {
            Segment::Decided(v) => visible[r] = v,
            Segment::Ray { o, d, len, t_min, t_max } => {
                if [&own[r], &*shared].into_iter().any(|h| pieces.remembered_stops(h, o, d, len, t_min, t_max)) {
                    visible[r] = false;
                    continue;
                }
                waiting.push(r, o, d, len, t_min, t_max);
                if waiting.n == PACKET {
                    waiting.walk(pieces, |r, hit| answered(r, hit, visible, own, shared));
                }
            }
        }
    }
    waiting.walk(pieces, |r, hit| answered(r, hit, visible, own, shared));
}

/// A walked ray's answer in [`visible_together`]: visible where nothing stops it, else the
/// piece remembered as the ray's and as the next ray's (`shared`).
fn answered(r: usize, hit: Option<(u32, u32)>, visible: &mut [bool], own: &mut [Occluder], shared: &mut Occluder) {
    visible[r] = hit.is_none();
    if let Some(hit) = hit {
        (own[r], *shared) = (Occluder(Some(hit)), Occluder(Some(hit)));
    }
}

/// Sun visibility bits of every problem row (rayon, 32 per task).
pub fn trace_sun(bvh: &Bvh, pb: &Rows, to_sun: Vec3, sky: &[bool]) -> Vec<u32> {
    let n = pb.len();
    (0..n.div_ceil(32))
        .into_par_iter()
        .map(|w| {
            let mut word = 0u32;
            for b in 0..32.min(n - w * 32) {
                let i = w * 32 + b;
                if sun_visible_from(bvh, pb.pos[i], pb.facing(i, to_sun), to_sun, &pb.sampling, sky, pb.solid_ahead[i]) {
                    word |= 1 << b;
                }
            }
            word
        })
        .collect()
}

/// How far a light can add anything under `sampling`: beyond `sqrt(I_max / falloff)` its
/// irradiance (at most `I / d^2`) is below the falloff tolerance; times `margin`.
/// Unlimited without a falloff.
pub fn reach(max_rgb: f32, sampling: &Sampling, margin: f32) -> f32 {
    if sampling.falloff > 0.0 {
        (max_rgb.max(0.0) / sampling.falloff).sqrt() * margin
    } else {
        f32::INFINITY
    }
}

/// The reach a light is traced to, relative to its current one: it may brighten by
/// `REACH_MARGIN^2` before it is traced again.
pub const REACH_MARGIN: f32 = 1.5;

/// Visibility bits of one light position from every row within `reach` meters (rayon,
/// 32 per task); farther rows get a clear bit without a ray.
pub fn trace_light(bvh: &Bvh, pb: &Rows, light: Vec3, reach: f32) -> Vec<u32> {
    trace_light_hinted(bvh, pb, light, reach, None).0
}

/// [`trace_light`] with each row's occluder from a trace of a light nearby (`prior`, one
/// per row) tried first, then the previous row's: the same bits. Also returns, per row,
/// the next trace's `prior` ([`RecentOccluders`]): what the walk found, or else the prior
/// where there was one (whether it or the previous row's answered), or else the previous
/// row's; a row whose ray was not stopped keeps its prior.
pub fn trace_light_hinted(bvh: &Bvh, pb: &Rows, light: Vec3, reach: f32, prior: Option<&[u64]>) -> (Vec<u32>, Vec<u64>) {
    let n = pb.len();
    let prior = prior.filter(|p| p.len() == n);
    let mut stopped = prior.map_or_else(|| vec![Occluder::default().packed(); n], <[u64]>::to_vec);
    let bits = stopped
        .par_chunks_mut(32)
        .enumerate()
        .map(|(w, stopped)| match &bvh.shadow {
            Some(pieces) => word_in_packets(pieces, pb, w, stopped, light, reach),
            None => {
                let mut word = 0u32;
                let mut last = Occluder::default();
                for (b, here) in stopped.iter_mut().enumerate() {
                    let i = w * 32 + b;
                    if (pb.pos[i] - light).length_squared() > reach * reach {
                        continue;
                    }
                    let mut mine = Occluder::unpacked(*here);
                    if visible_hinted(bvh, pb.pos[i], pb.facing(i, light - pb.pos[i]), light, &pb.sampling, &mut [&mut mine, &mut last]) {
                        word |= 1 << b;
                    } else {
                        *here = if mine.0.is_some() { mine } else { last }.packed();
                    }
                }
                word
            }
        })
        .collect();
    (bits, stopped)
}

/// One word of [`trace_light_hinted`] through q3map2's pieces: each row's segment
/// ([`shadow_segment`]) tries the row's prior and the previous row's occluder, as
/// [`visible_hinted`] does; the rows they do not stop wait, and are walked [`PACKET`] at a
/// time ([`Shadow::occluders_packet`]: consecutive rows towards one light cross mostly the
/// same boxes, each loaded once for all of them). Each row's bit is its own walk's; only
/// which piece is remembered for the next trace can differ from a walk per row.
fn word_in_packets(pieces: &Shadow, pb: &Rows, w: usize, stopped: &mut [u64], light: Vec3, reach: f32) -> u32 {
    let mut word = 0u32;
    let mut last = Occluder::default();
    let mut waiting = Waiting::default();
    for b in 0..stopped.len() {
        let i = w * 32 + b;
        if (pb.pos[i] - light).length_squared() > reach * reach {
            continue;
        }
        let x = pb.pos[i];
        match shadow_segment(x, pb.facing(i, light - x), light, &pb.sampling) {
            Segment::Decided(true) => word |= 1 << b,
            Segment::Decided(false) => {
                let mine = Occluder::unpacked(stopped[b]);
                stopped[b] = if mine.0.is_some() { mine } else { last }.packed();
            }
            Segment::Ray { o, d, len, t_min, t_max } => {
                let mine = Occluder::unpacked(stopped[b]);
                if [&mine, &last].into_iter().any(|h| pieces.remembered_stops(h, o, d, len, t_min, t_max)) {
                    stopped[b] = if mine.0.is_some() { mine } else { last }.packed();
                    continue;
                }
                waiting.push(b, o, d, len, t_min, t_max);
                if waiting.n == PACKET {
                    waiting.walk(pieces, |b, hit| remember(b, hit, &mut word, &mut last, stopped));
                }
            }
        }
    }
    waiting.walk(pieces, |b, hit| remember(b, hit, &mut word, &mut last, stopped));
    word
}

/// A walked row's answer in [`word_in_packets`]: its bit where nothing stops it, else the
/// piece remembered as the row's and as the previous row's (`last`).
fn remember(b: usize, hit: Option<(u32, u32)>, word: &mut u32, last: &mut Occluder, stopped: &mut [u64]) {
    match hit {
        Some(hit) => {
            *last = Occluder(Some(hit));
            stopped[b] = last.packed();
        }
        None => *word |= 1 << b,
    }
}

/// Segments waiting for [`Shadow::occluders_packet`]: `n` of them, each with its
/// caller's index.
#[derive(Default)]
struct Waiting {
    n: usize,
    index: [usize; PACKET],
    o: [Vec3; PACKET],
    d: [Vec3; PACKET],
    len: [f32; PACKET],
    t_min: [f32; PACKET],
    t_max: [f32; PACKET],
}

impl Waiting {
    fn push(&mut self, index: usize, o: Vec3, d: Vec3, len: f32, t_min: f32, t_max: f32) {
        let r = self.n;
        (self.index[r], self.o[r], self.d[r], self.len[r], self.t_min[r], self.t_max[r]) = (index, o, d, len, t_min, t_max);
        self.n += 1;
    }

    /// Walks the waiting segments together and tells `answer(index, occluder)` each one's
    /// piece (`None`: nothing stops it), in the order they came. None wait after.
    fn walk(&mut self, pieces: &Shadow, mut answer: impl FnMut(usize, Option<(u32, u32)>)) {
        if self.n == 0 {
            return;
        }
        let found = pieces.occluders_packet(&self.o, &self.d, &self.len, &self.t_min, &self.t_max, (1u32 << self.n) - 1);
        for (r, &index) in self.index[..self.n].iter().enumerate() {
            answer(index, found[r]);
        }
        self.n = 0;
    }
}

/// A shadow ray as [`visible_hinted`] sets it up: decided without a walk, or the segment
/// `o + s d`, `s` in `(t_min, t_max)` (`len = |d|`) that geometry must not cross.
enum Segment {
    Decided(bool),
    Ray { o: Vec3, d: Vec3, len: f32, t_min: f32, t_max: f32 },
}

/// [`visible_hinted`]'s segment from `x` (normal `n`) to `light`.
#[inline]
fn shadow_segment(x: Vec3, n: Vec3, light: Vec3, s: &Sampling) -> Segment {
    let (offset, inhibit, end) = (s.shadow_offset, s.inhibit, s.ray_offset);
    if n.dot(light - x) <= 0.0 {
        return Segment::Decided(false);
    }
    let o = x + n * offset;
    let d = light - o;
    let len = d.length();
    if !(len > offset.max(inhibit)) {
        // The light touches the surface: lit, nothing can be in between.
        return Segment::Decided(len.is_finite());
    }
    Segment::Ray { o, d, len, t_min: inhibit / len, t_max: 1.0 - end / len }
}

/// The occluders of recent light traces by light position ([`trace_light_hinted`]): a
/// light traced again a few centimetres from where it was (a fit's step) mostly meets the
/// pieces that stopped its rays there, and tries them first. Most recent last; at most
/// [`RECENT_OCCLUDER_BYTES`].
#[derive(Debug, Default)]
pub struct RecentOccluders {
    /// Per trace: its light and, per row, [`Occluder::packed`].
    entries: std::collections::VecDeque<(Vec3, Vec<u64>)>,
}

/// Most bytes [`RecentOccluders`] keeps.
pub const RECENT_OCCLUDER_BYTES: usize = 128 << 20;

/// Farthest a kept trace's light may be from the light traced for its occluders to be
/// tried, m.
pub const RECENT_OCCLUDER_RADIUS_M: f32 = 1.0;

impl RecentOccluders {
    /// The occluders of the kept trace whose light was nearest `p`, within
    /// [`RECENT_OCCLUDER_RADIUS_M`].
    pub fn near(&self, p: Vec3) -> Option<&[u64]> {
        let best = self.entries.iter().map(|(q, o)| ((*q - p).length_squared(), o)).filter(|(d2, _)| *d2 <= RECENT_OCCLUDER_RADIUS_M * RECENT_OCCLUDER_RADIUS_M).min_by(|a, b| a.0.total_cmp(&b.0));
        best.map(|(_, o)| o.as_slice())
    }

    /// Keeps the occluders of a trace from `p`, dropping the oldest over the budget.
    pub fn put(&mut self, p: Vec3, occluders: Vec<u64>) {
        let bytes = (occluders.len() * std::mem::size_of::<u64>()).max(1);
        let most = RECENT_OCCLUDER_BYTES / bytes;
        if most == 0 {
            return;
        }
        while self.entries.len() >= most {
            self.entries.pop_front();
        }
        self.entries.push_back((p, occluders));
    }
}

/// One shadow ray (the CPU reference of the WGSL `visible_from`): from `x + n offset`
/// to the light, ignoring geometry within `inhibit` of the ray's start.
pub fn visible_from(bvh: &Bvh, x: Vec3, n: Vec3, light: Vec3, s: &Sampling) -> bool {
    visible_after(bvh, x, n, light, s, &mut Occluder::default())
}

/// [`visible_from`] with the occluder of the previous ray towards the same light tried
/// first ([`Tree::occluded_after`](crate::trace::tree::Tree::occluded_after); the same answer).
pub fn visible_after(bvh: &Bvh, x: Vec3, n: Vec3, light: Vec3, s: &Sampling, last: &mut Occluder) -> bool {
    visible_hinted(bvh, x, n, light, s, &mut [last])
}

/// [`visible_after`] with several remembered occluders, tried in order (the same answer):
/// a row's previous ray and the previous row's ray to the same target, say.
pub fn visible_hinted(bvh: &Bvh, x: Vec3, n: Vec3, light: Vec3, s: &Sampling, hints: &mut [&mut Occluder]) -> bool {
    // Geometry within `end` of the light does not shadow it (a light on a face: q3map2's
    // f32 depth of that face decides it ray by ray, a pattern no model reproduces).
    let (o, d, t_min, t_max) = match shadow_segment(x, n, light, s) {
        Segment::Decided(v) => return v,
        Segment::Ray { o, d, t_min, t_max, .. } => (o, d, t_min, t_max),
    };
    if let Some(pieces) = &bvh.shadow {
        return !pieces.occluded_hinted(o, d, t_min, t_max, hints);
    }
    !bvh.occluded_hinted(o, d, t_min, t_max, hints)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::{Backend, Cpu};
    use crate::model::bounce::hash01;

    /// A snapshot names the state it was taken of: a clone of it, and an update that
    /// traced nothing, still are it; a light traced again (even to the same bits), a light
    /// removed or added, and a turned sun are not.
    #[test]
    fn a_snapshot_names_the_state_an_evaluation_read() {
        let sampling = crate::rows::Sampling::default();
        let mut v = Visibility::default();
        v.push_traced(vec![0b1011], Vec3::ZERO, f32::INFINITY);
        v.push_traced(vec![0b0110], Vec3::ONE, f32::INFINITY);
        v.sun = Some((Vec3::Y, vec![0b1]));
        let s = v.snapshot();
        assert!(v.is(&s) && v.clone().is(&s));
        let mut nothing = |_: &[(Vec3, f32)]| -> crate::error::Result<Vec<Vec<u32>>> { panic!("nothing is stale") };
        let mut still = v.clone();
        assert_eq!(still.update(&[(Vec3::ZERO, 0.0), (Vec3::ONE, 0.0)], 0.1, &sampling, 4, &mut nothing).unwrap(), 0);
        assert!(still.is(&s));
        let mut again = v.clone();
        again.set_traced(0, vec![0b1011], Vec3::ZERO, f32::INFINITY);
        assert!(!again.is(&s), "traced again");
        let mut fewer = v.clone();
        fewer.remove(1);
        assert!(!fewer.is(&s), "a light removed");
        let mut more = v.clone();
        more.push_traced(vec![0], Vec3::X, 1.0);
        assert!(!more.is(&s), "a light added");
        let mut turned = v.clone();
        turned.sun = Some((Vec3::X, vec![0b1]));
        assert!(!turned.is(&s), "the sun turned");
        let mut shaded = v;
        shaded.sun = Some((Vec3::Y, vec![0b0]));
        assert!(!shaded.is(&s), "the sun's bits changed");
    }

    /// The set bits within a range, each once, in ascending order: what testing every
    /// row's bit gives (ranges that start and end inside a word, at a word's edge, empty,
    /// and past the bits' end).
    #[test]
    fn each_set_bit_visits_what_a_test_of_every_bit_visits() {
        let bits: Vec<u32> = (0..5u32).map(|w| (hash01(w, 7) * u32::MAX as f32) as u32 & (hash01(w, 8) * u32::MAX as f32) as u32).collect();
        for (start, end) in [(0, 160), (3, 29), (31, 33), (32, 64), (40, 40), (5, 200), (150, 170), (64, 65)] {
            let mut seen = Vec::new();
            each_set_bit(&bits, start..end, |i| seen.push(i));
            let every: Vec<usize> = (start..end.min(160)).filter(|&i| bits[i >> 5] >> (i & 31) & 1 == 1).collect();
            assert_eq!(seen, every, "rows {start}..{end}");
        }
    }

    /// Every row gets its own state, sees every source once and in order, and the rows
    /// come back in order; each source's hint passes from row to row within a block only.
    #[test]
    fn neighbour_blocks_visit_each_rows_sources_in_order() {
        for n in [0, 1, HINT_ROWS - 1, HINT_ROWS, 3 * HINT_ROWS + 5] {
            let sources = 7;
            let out = by_neighbour_blocks(
                n,
                sources,
                |i| (i, Vec::new()),
                || None::<usize>,
                |i, k, (row, seen): &mut (usize, Vec<usize>), hint: &mut Option<usize>| {
                    assert_eq!(*row, i);
                    // The previous row of this block that saw source k, if any.
                    if let Some(prev) = *hint {
                        assert!(prev + 1 == i && prev / HINT_ROWS == i / HINT_ROWS, "{prev} -> {i}");
                    } else {
                        assert_eq!(i % HINT_ROWS, 0, "row {i}: the hint starts fresh only at a block's first row");
                    }
                    *hint = Some(i);
                    seen.push(k);
                },
            );
            assert_eq!(out.len(), n);
            for (i, (row, seen)) in out.iter().enumerate() {
                assert_eq!((*row, seen.clone()), (i, (0..sources).collect::<Vec<_>>()));
            }
        }
    }

    /// Through q3map2's pieces a word's rows are walked several at a time
    /// (`word_in_packets`): every bit is what one ray's own walk gives (`visible_from`),
    /// with no prior, with a prior from a trace nearby and with nonsense for one; and each
    /// occluder it hands on stops its row's ray.
    #[test]
    fn rows_walked_together_get_each_rows_own_bit() {
        let (mut mesh, mut rows) = crate::testutil::room(8);
        crate::testutil::scatter_quads(&mut mesh, 300);
        rows.sampling.inhibit = 0.01;
        // The casters in Quake units, a tree of two planes through the room.
        let c = crate::testutil::casters_of(&mesh, 60.0, 40.0);
        let mut bvh = Bvh::build(&mesh);
        bvh.shadow = Some(Box::new(crate::trace::pieces::Shadow::new(&c, glam::DVec3::ZERO, q3gltf_convert::units::DEFAULT_SCALE)));
        let (mut lit, mut blocked) = (0, 0);
        for k in 0..12u32 {
            let p = Vec3::new(0.2 + 3.6 * hash01(k, 31), 0.2 + 2.6 * hash01(k, 32), 0.2 + 3.6 * hash01(k, 33));
            let reach = if k % 3 == 0 { 2.5 } else { f32::INFINITY };
            let reference: Vec<bool> = (0..rows.len()).map(|i| (rows.pos[i] - p).length_squared() <= reach * reach && visible_from(&bvh, rows.pos[i], rows.facing(i, p - rows.pos[i]), p, &rows.sampling)).collect();
            let bit = |bits: &[u32], i: usize| bits[i >> 5] >> (i & 31) & 1 == 1;
            let (bits, first) = trace_light_hinted(&bvh, &rows, p, reach, None);
            for i in 0..rows.len() {
                assert_eq!(bit(&bits, i), reference[i], "light {k}, row {i}");
                if !reference[i] && first[i] != u64::MAX {
                    let mut only = Occluder::unpacked(first[i]);
                    assert!(!visible_hinted(&bvh, rows.pos[i], rows.facing(i, p - rows.pos[i]), p, &rows.sampling, &mut [&mut only]), "light {k}, row {i}: its occluder");
                }
                lit += reference[i] as usize;
                blocked += (!reference[i] && (rows.pos[i] - p).length_squared() <= reach * reach && rows.normal[i].dot(p - rows.pos[i]) > 0.0) as usize;
            }
            let q = p + Vec3::new(0.03, -0.02, 0.01);
            let moved: Vec<bool> = (0..rows.len()).map(|i| (rows.pos[i] - q).length_squared() <= reach * reach && visible_from(&bvh, rows.pos[i], rows.facing(i, q - rows.pos[i]), q, &rows.sampling)).collect();
            let junk: Vec<u64> = (0..rows.len() as u32).map(|i| Occluder(Some((i % 7, i.wrapping_mul(2654435761) % 9000))).packed()).collect();
            for prior in [&first, &junk] {
                let (again, _) = trace_light_hinted(&bvh, &rows, q, reach, Some(prior));
                assert!((0..rows.len()).all(|i| bit(&again, i) == moved[i]), "light {k}, moved, with a prior");
            }
        }
        assert!(lit > 1000 && blocked > 1000, "both answers exercised: {lit} lit, {blocked} blocked");
    }

    /// A light traced with the occluders of a trace nearby, or with nonsense for them,
    /// gets the bits of a trace without any; the occluders it hands on stop their rows'
    /// rays, and a light moved a few centimetres finds most of them again. The CPU
    /// backend, which keeps them, traces as `trace_light` does.
    #[test]
    fn remembered_occluders_change_no_bit() {
        let (mut mesh, rows) = crate::testutil::room(8);
        crate::testutil::scatter_quads(&mut mesh, 300);
        let bvh = Bvh::build(&mesh);
        let mut cpu = Cpu::new(&rows, &bvh);
        let (mut blocked, mut found_again) = (0, 0);
        for k in 0..12u32 {
            let p = Vec3::new(0.2 + 3.6 * hash01(k, 21), 0.2 + 2.6 * hash01(k, 22), 0.2 + 3.6 * hash01(k, 23));
            let reach = if k % 3 == 0 { 2.5 } else { f32::INFINITY };
            let fresh = trace_light(&bvh, &rows, p, reach);
            let (bits, first) = trace_light_hinted(&bvh, &rows, p, reach, None);
            assert_eq!(bits, fresh, "light {k}, no prior");
            // What it hands on stopped its rows' rays: each alone gives the answer.
            for i in 0..rows.len() {
                let lit = fresh[i >> 5] >> (i & 31) & 1 == 1;
                let out_of_reach = (rows.pos[i] - p).length_squared() > reach * reach;
                if !lit && !out_of_reach && rows.normal[i].dot(p - rows.pos[i]) > 0.0 {
                    let mut only = Occluder::unpacked(first[i]);
                    assert!(only.0.is_some(), "light {k}, row {i}: a blocked row names its occluder");
                    assert!(!visible_hinted(&bvh, rows.pos[i], rows.facing(i, p - rows.pos[i]), p, &rows.sampling, &mut [&mut only]));
                    blocked += 1;
                }
            }
            // Moved 3 cm: the same bits as a fresh trace there, and the same occluders met.
            let q = p + Vec3::new(0.03, -0.02, 0.01);
            let (moved, again) = trace_light_hinted(&bvh, &rows, q, reach, Some(&first));
            assert_eq!(moved, trace_light(&bvh, &rows, q, reach), "light {k}, moved");
            found_again += first.iter().zip(&again).filter(|(a, b)| **a != u64::MAX && a == b).count();
            // Nonsense remembered: indices past the tree, leaves that are not leaves.
            let junk: Vec<u64> = (0..rows.len() as u32).map(|i| Occluder(Some((hash01(i, k) as u32 * 7 + i % 5, i.wrapping_mul(2654435761) % 9000))).packed()).collect();
            assert_eq!(trace_light_hinted(&bvh, &rows, q, reach, Some(&junk)).0, moved, "light {k}, junk");
            // The backend keeps its traces' occluders and answers as the plain trace.
            for pos in [p, q, p] {
                assert_eq!(cpu.trace(&[(pos, reach)]).unwrap(), vec![trace_light(&bvh, &rows, pos, reach)], "light {k}, backend");
            }
        }
        assert!(blocked > 1000, "the scene blocks rays: {blocked}");
        assert!(found_again * 10 > blocked * 8, "most occluders are met again 3 cm away: {found_again} of {blocked}");
    }
}
