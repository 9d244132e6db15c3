//! The model a file states: what a renderer of the glTF as it is would light it with,
//! in the terms of this model. Used to bake a relit scene ([`crate::bake`]) and to check
//! a file's own light against its lightmaps.
//!
//! | term | from the file |
//! |---|---|
//! | point and spot lights | `KHR_lights_punctual` point and spot lights ([`Light::from_input`]) |
//! | sun | the first directional light (lux / 683 = W/m^2) |
//! | surface lights | each emitting shader's emission, `emissiveFactor x emissiveStrength` (W/(m^2 sr)); an emissive material without q3map2's `q3_surfacelight` extras (one made in Blender) becomes a surface light of its own, without backsplash |
//! | sky light | the sky materials' emission `L`: `K = pi L / mean_cos_up`, the inverse of how relight writes it ([`crate::model::sky`]) |
//! | ambient, minlight, bounce, dirt, filter | the scene extras `q3_relight` that relight writes ([`crate::scene::Relit`]) |
//!
//! Terms the file does not state are off: a converted (not relit) file states its
//! surface lights and, with `--lights-from`, its light entities and sun.

use crate::io::lights_out::LM_PER_W;
use crate::model::{sky, surface, Light, Model, Sun};
use crate::scene::{Emitter, Lighting, Scene};

/// The stated model and the passes of bounced light it wants.
#[derive(Debug, Clone)]
pub struct Stated {
    pub model: Model,
    /// Passes of bounced light (0 without a bounce term).
    pub bounces: usize,
    /// What was assumed or left out, for the report.
    pub notes: Vec<String>,
}

/// Largest channel.
fn max3(v: [f32; 3]) -> f32 {
    v[0].max(v[1]).max(v[2])
}

/// The model `scene` states (see the module docs). Emissive materials without a q3map2
/// emitter get one in `scene` (so that [`surface::basis`] groups them). `bounces`
/// overrides the recorded passes of bounced light (at the recorded scale, 1 when the file
/// records none; `Some(0)`: no bounce).
pub fn stated(scene: &mut Scene, bounces: Option<usize>) -> Stated {
    let mut notes = Vec::new();
    let lights: Vec<Light> = scene.lights.iter().map(Light::from_input).collect();
    let sun = scene.suns.first().map(|s| Sun { to_sun: s.to_sun, rgb: s.color.map(|c| (c as f64 * s.intensity_lux as f64 / LM_PER_W) as f32) });
    if scene.suns.len() > 1 {
        notes.push(format!("{} directional lights: the model has one sun, the first ({}) is used", scene.suns.len(), scene.suns[0].name));
    }
    // Emission without a q3map2 emitter: a surface light of its own.
    let ob = scene.materials.iter().find(|m| m.lighting != Lighting::None).map_or(2, |m| m.overbright_bits);
    let l_per_value = q3gltf_convert::units::Q3MAP2_SURFACE_SCALE as f32 * q3gltf_convert::units::e_per_byte(ob) as f32;
    let mut made = 0;
    for m in scene.materials.iter_mut() {
        let peak = max3(m.emission);
        if m.sky || m.emitter.is_some() || !(peak > 0.0) || !(l_per_value > 0.0) {
            continue;
        }
        m.emitter = Some(Emitter { value: peak / l_per_value, color: m.emission.map(|c| c / peak), subdivide: 999.0, backsplash: (0.0, 0.0) });
        made += 1;
    }
    if made > 0 {
        notes.push(format!("{made} emissive materials without q3map2 surface-light extras lit as surface lights (no backsplash)"));
    }
    let groups = surface::patches(scene).0;
    let surfaces = surface_emission(scene, &groups);
    let dark = surfaces.iter().filter(|s| s.is_none()).count();
    if dark > 0 {
        notes.push(format!("{dark} surface-light shaders have no emission in the file: left dark"));
    }
    let sky = sky_of(scene);
    let relit = scene.relit.clone().unwrap_or_default();
    // The recorded bounce (its scale and passes), or the passes asked for at the recorded
    // scale (1 where none is recorded).
    let (bounce, passes) = match (bounces, relit.bounce_scale) {
        (Some(n), s) if n > 0 => (Some(s.unwrap_or([1.0; 3])), n),
        (None, Some(s)) if relit.bounces > 0 => (Some(s), relit.bounces),
        _ => (None, 0),
    };
    if scene.relit.is_none() {
        notes.push("no q3_relight scene extras (not relit, or exported from Blender without custom properties): no ambient, minlight, dirt or filter".into());
    }
    Stated { model: Model { lights, sun, sky, surfaces, ambient: relit.ambient, bounce, minlight: relit.minlight, gathered: None, dirt: relit.dirt, filter: relit.filter }, bounces: passes, notes }
}

/// Each surface-light group's emission in the file, W/(m^2 sr) (`None`: dark).
fn surface_emission(scene: &Scene, groups: &[surface::Group]) -> Vec<Option<[f32; 3]>> {
    groups.iter().map(|g| g.materials.iter().filter_map(|&m| scene.materials.get(m as usize)).map(|m| m.emission).find(|e| max3(*e) > 0.0)).collect()
}

/// The sky light `K` the sky materials' emission stands for, as relight writes it.
fn sky_of(scene: &Scene) -> Option<[f32; 3]> {
    let l = scene.materials.iter().filter(|m| m.sky).map(|m| m.emission).find(|e| max3(*e) > 0.0)?;
    let it = scene.materials.iter().flat_map(|m| m.sky_lights.iter()).map(|s| s.1).max().unwrap_or(8);
    let dirs = sky::directions(it);
    let mean_cos_up = dirs.iter().map(|w| w.y.max(0.0)).sum::<f32>() / dirs.len().max(1) as f32;
    (mean_cos_up > 0.0).then(|| l.map(|v| std::f32::consts::PI * v / mean_cos_up))
}

/// The start of `relight --init input` on a file that relight wrote (scene extras
/// `q3_relight`): the terms as the file states them, in place of the declared ones of
/// `start` (q3map2's source values of the surface lights and the sky, the compile's
/// ambient), so that a re-run starts where the previous fit ended: a surface light it
/// switched off stays dark, the ambient, minlight, bounce scale, dirt and filter are the
/// fitted ones. Terms whose basis `bases` lacks stay as `start` has them. `None` for a
/// file without those extras (a converted file, or one Blender exported without custom
/// properties): the declared start stands.
pub fn resumed(start: &Model, scene: &Scene, bases: &crate::model::Bases) -> Option<Model> {
    let relit = scene.relit.as_ref()?;
    let mut m = start.clone();
    m.surfaces = surface_emission(scene, &bases.surfaces.groups);
    if bases.sky.is_some() {
        m.sky = sky_of(scene);
    }
    m.ambient = relit.ambient;
    m.minlight = relit.minlight;
    if bases.bounce.is_some() {
        m.bounce = relit.bounce_scale.filter(|_| relit.bounces > 0);
    }
    m.dirt = relit.dirt.filter(|s| bases.dirt.iter().any(|b| b.settings == *s));
    m.filter = relit.filter && bases.filter.is_some();
    Some(m)
}
