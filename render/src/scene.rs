//! Scenes: a list of textured analytic surfaces and a background, and ray casting into them.

use std::sync::Arc;

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};

use crate::{RenderError, Result, Texture};

/// Rays hit nothing closer than this (in units of the ray direction's length, ~metres), so a
/// camera sitting exactly on a surface does not see it.
const T_MIN: f64 = 1e-9;

/// Textures of a box's faces.
#[derive(Debug, Clone)]
pub enum BoxTextures {
    /// The same texture on all six faces.
    One(Arc<Texture>),
    /// One texture per face, in the order +x, -x, +y, -y, +z, -z (local axes). Face
    /// coordinates: on the x faces u runs along +z and v along +y; on the y faces u along +x and
    /// v along +z; on the z faces u along +x and v along +y (each from the face's minimum corner).
    PerFace([Arc<Texture>; 6]),
}

impl BoxTextures {
    fn face(&self, f: usize) -> &Texture {
        match self {
            BoxTextures::One(t) => t,
            BoxTextures::PerFace(t) => &t[f],
        }
    }

    fn all(&self) -> Vec<&Arc<Texture>> {
        match self {
            BoxTextures::One(t) => vec![t],
            BoxTextures::PerFace(t) => t.iter().collect(),
        }
    }
}

/// One textured surface. All surfaces are two-sided and opaque.
#[derive(Debug, Clone)]
pub enum Surface {
    /// A rectangle in the local plane z = 0 covering x in [0, w], y in [0, h] (metres), with the
    /// texture's (u, v) = (x / w, y / h): the local origin is the texture's top-left corner, so a
    /// calibration board's own frame (origin at a corner, x along rows, y down columns) is the
    /// local frame. A camera at the identity looking at `world_from_local = translation(0,0,d)`
    /// sees the texture upright and unmirrored.
    Rect { world_from_local: Isometry3<f64>, size: [f64; 2], texture: Arc<Texture> },
    /// A box centred on its local origin with the given half extents (metres).
    Cuboid { world_from_local: Isometry3<f64>, half_extents: Vector3<f64>, textures: BoxTextures },
    /// A sphere, textured by longitude/latitude: u = 0.5 + atan2(x, z) / 2pi, v = acos(-y) / pi
    /// of the unit normal in world axes (v = 0 at the top, -y, in the OpenCV-style world).
    Sphere { centre: Point3<f64>, radius: f64, texture: Arc<Texture> },
}

impl Surface {
    /// A `w x h` metre rectangle whose local origin (texture top-left corner) is at `world_from_local`.
    pub fn rect(world_from_local: Isometry3<f64>, w: f64, h: f64, texture: impl Into<Arc<Texture>>) -> Result<Surface> {
        let s = Surface::Rect { world_from_local, size: [w, h], texture: texture.into() };
        s.validate(0)?;
        Ok(s)
    }

    /// A `w x h` metre rectangle posed by its centre (`world_from_centre`, same axes as [`Surface::Rect`]).
    pub fn rect_centred(
        world_from_centre: Isometry3<f64>,
        w: f64,
        h: f64,
        texture: impl Into<Arc<Texture>>,
    ) -> Result<Surface> {
        let corner = Isometry3::translation(-w / 2.0, -h / 2.0, 0.0);
        Surface::rect(world_from_centre * corner, w, h, texture)
    }

    /// A box with one texture on every face.
    pub fn cuboid(
        world_from_local: Isometry3<f64>,
        half_extents: Vector3<f64>,
        texture: impl Into<Arc<Texture>>,
    ) -> Result<Surface> {
        Surface::cuboid_faces(world_from_local, half_extents, BoxTextures::One(texture.into()))
    }

    /// A box with per-face textures.
    pub fn cuboid_faces(
        world_from_local: Isometry3<f64>,
        half_extents: Vector3<f64>,
        textures: BoxTextures,
    ) -> Result<Surface> {
        let s = Surface::Cuboid { world_from_local, half_extents, textures };
        s.validate(0)?;
        Ok(s)
    }

    /// A sphere.
    pub fn sphere(centre: Point3<f64>, radius: f64, texture: impl Into<Arc<Texture>>) -> Result<Surface> {
        let s = Surface::Sphere { centre, radius, texture: texture.into() };
        s.validate(0)?;
        Ok(s)
    }

    fn kind(&self) -> &'static str {
        match self {
            Surface::Rect { .. } => "rect",
            Surface::Cuboid { .. } => "box",
            Surface::Sphere { .. } => "sphere",
        }
    }

    fn textures(&self) -> Vec<&Arc<Texture>> {
        match self {
            Surface::Rect { texture, .. } | Surface::Sphere { texture, .. } => vec![texture],
            Surface::Cuboid { textures, .. } => textures.all(),
        }
    }

    /// Checks sizes and poses (`index` only labels the error).
    pub fn validate(&self, index: usize) -> Result<()> {
        let bad = |reason: String| Err(RenderError::InvalidSurface { index, kind: self.kind(), reason });
        let pose_ok = |p: &Isometry3<f64>| {
            p.translation.vector.iter().all(|v| v.is_finite()) && p.rotation.coords.iter().all(|v| v.is_finite())
        };
        let pos = |v: f64| v.is_finite() && v > 0.0;
        match self {
            Surface::Rect { world_from_local, size, .. } => {
                if !pos(size[0]) || !pos(size[1]) {
                    return bad(format!("size {} x {} m must be positive and finite", size[0], size[1]));
                }
                if !pose_ok(world_from_local) {
                    return bad("pose is not finite".into());
                }
            }
            Surface::Cuboid { world_from_local, half_extents, .. } => {
                if !half_extents.iter().all(|&v| pos(v)) {
                    return bad(format!(
                        "half extents {} x {} x {} m must be positive and finite",
                        half_extents.x, half_extents.y, half_extents.z
                    ));
                }
                if !pose_ok(world_from_local) {
                    return bad("pose is not finite".into());
                }
            }
            Surface::Sphere { centre, radius, .. } => {
                if !pos(*radius) {
                    return bad(format!("radius {radius} m must be positive and finite"));
                }
                if !centre.coords.iter().all(|v| v.is_finite()) {
                    return bad("centre is not finite".into());
                }
            }
        }
        Ok(())
    }
}

/// A scene: opaque surfaces in front of a uniform background.
#[derive(Debug, Clone)]
pub struct Scene {
    /// Surfaces; where two are hit at exactly the same distance the earlier one wins.
    pub surfaces: Vec<Surface>,
    /// Radiance in [0, 1] where a ray hits nothing (depth is then infinite). For a textured
    /// backdrop add a large far [`Surface::Rect`] (its depth is then finite).
    pub background: f32,
}

/// Where a ray hits the scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Index into [`Scene::surfaces`].
    pub surface: usize,
    /// Ray parameter: the hit is `origin + t * dir` (metres when `dir` is a unit vector).
    pub t: f64,
    /// The hit point in the world frame.
    pub point: Point3<f64>,
}

impl Scene {
    /// A scene without surfaces.
    pub fn new(background: f32) -> Scene {
        Scene { surfaces: Vec::new(), background }
    }

    /// Adds a surface (builder style).
    pub fn with(mut self, surface: Surface) -> Scene {
        self.surfaces.push(surface);
        self
    }

    /// Checks every surface, and the background.
    pub fn validate(&self) -> Result<()> {
        if !self.background.is_finite() {
            return Err(RenderError::InvalidOptions(format!("background {} is not finite", self.background)));
        }
        self.surfaces.iter().enumerate().try_for_each(|(i, s)| s.validate(i))
    }

    /// Whether any texture carries colour (then renders also produce RGB).
    pub fn has_rgb(&self) -> bool {
        self.surfaces.iter().any(|s| s.textures().iter().any(|t| t.is_rgb()))
    }

    /// Casts one world-frame ray: the nearest hit with `t > 0`, if any. Used e.g. to check
    /// whether a board corner is visible (`cast` from the camera centre towards it).
    pub fn cast(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
        let frame = Frame::new(self, &Isometry3::translation(origin.x, origin.y, origin.z));
        let (surface, t, _) = frame.trace(dir)?;
        Some(Hit { surface, t, point: origin + dir * t })
    }
}

/// A surface seen from one camera pose: the ray's origin and rotation into the local frame, so
/// each camera-frame ray costs one 3x3 product per surface.
struct Prepared<'a> {
    local_from_camera: Matrix3<f64>,
    origin: Vector3<f64>,
    surface: &'a Surface,
}

/// A scene prepared for one camera pose.
pub(crate) struct Frame<'a> {
    surfaces: Vec<Prepared<'a>>,
}

impl<'a> Frame<'a> {
    pub(crate) fn new(scene: &'a Scene, world_from_camera: &Isometry3<f64>) -> Frame<'a> {
        let surfaces = scene
            .surfaces
            .iter()
            .map(|surface| {
                let local_from_camera = match surface {
                    Surface::Rect { world_from_local, .. } | Surface::Cuboid { world_from_local, .. } => {
                        world_from_local.inverse() * world_from_camera
                    }
                    Surface::Sphere { centre, .. } => {
                        Isometry3::translation(-centre.x, -centre.y, -centre.z) * world_from_camera
                    }
                };
                Prepared {
                    local_from_camera: local_from_camera.rotation.to_rotation_matrix().into_inner(),
                    origin: local_from_camera.translation.vector,
                    surface,
                }
            })
            .collect();
        Frame { surfaces }
    }

    /// Nearest hit of a camera-frame ray: (surface index, t, local direction's face/aux code).
    #[inline]
    pub(crate) fn trace(&self, dir: &Vector3<f64>) -> Option<(usize, f64, u8)> {
        let mut best: Option<(usize, f64, u8)> = None;
        for (i, s) in self.surfaces.iter().enumerate() {
            let d = s.local_from_camera * dir;
            let o = &s.origin;
            let hit = match s.surface {
                Surface::Rect { size, .. } => {
                    let t = -o.z / d.z;
                    if t > T_MIN {
                        let x = o.x + t * d.x;
                        let y = o.y + t * d.y;
                        if (0.0..=size[0]).contains(&x) && (0.0..=size[1]).contains(&y) {
                            Some((t, 0))
                        } else {
                            None
                        }
                    } else {
                        None
                    }
                }
                Surface::Cuboid { half_extents: h, .. } => {
                    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
                    let (mut f0, mut f1) = (0u8, 0u8);
                    for a in 0..3 {
                        let inv = 1.0 / d[a];
                        let ta = (-h[a] - o[a]) * inv;
                        let tb = (h[a] - o[a]) * inv;
                        // Entering through the -a face when the ray goes towards +a.
                        let (tn, tf, fn_, ff) = if ta < tb {
                            (ta, tb, 2 * a as u8 + 1, 2 * a as u8)
                        } else {
                            (tb, ta, 2 * a as u8, 2 * a as u8 + 1)
                        };
                        if tn > t0 {
                            t0 = tn;
                            f0 = fn_;
                        }
                        if tf < t1 {
                            t1 = tf;
                            f1 = ff;
                        }
                    }
                    if t1 < t0 || t1 <= T_MIN {
                        None
                    } else if t0 > T_MIN {
                        Some((t0, f0))
                    } else {
                        Some((t1, f1))
                    }
                }
                Surface::Sphere { radius, .. } => {
                    let a = d.norm_squared();
                    let b = o.dot(&d);
                    let c = o.norm_squared() - radius * radius;
                    let disc = b * b - a * c;
                    if disc < 0.0 {
                        None
                    } else {
                        let sq = disc.sqrt();
                        // Numerically stable roots: q = -(b + sign(b) sq).
                        let q = -(b + b.signum() * sq);
                        let (r0, r1) = (q / a, c / q);
                        let (tn, tf) = if r0 < r1 { (r0, r1) } else { (r1, r0) };
                        if tn > T_MIN {
                            Some((tn, 0))
                        } else if tf > T_MIN {
                            Some((tf, 0))
                        } else {
                            None
                        }
                    }
                }
            };
            if let Some((t, aux)) = hit {
                if best.is_none_or(|(_, bt, _)| t < bt) {
                    best = Some((i, t, aux));
                }
            }
        }
        best
    }

    /// Texture coordinates and texture of a hit found by [`Frame::trace`].
    #[inline]
    fn surface_uv(&self, i: usize, dir: &Vector3<f64>, t: f64, aux: u8) -> (&Texture, f64, f64) {
        let s = &self.surfaces[i];
        let p = s.origin + t * (s.local_from_camera * dir);
        match s.surface {
            Surface::Rect { size, texture, .. } => {
                let (u, v) = texture.uv_on_face(p.x, p.y, size[0], size[1]);
                (texture, u, v)
            }
            Surface::Cuboid { half_extents: h, textures, .. } => {
                let f = aux as usize;
                let (ua, va) = match f / 2 {
                    0 => (2, 1),
                    1 => (0, 2),
                    _ => (0, 1),
                };
                let tex = textures.face(f);
                let (u, v) = tex.uv_on_face(p[ua] + h[ua], p[va] + h[va], 2.0 * h[ua], 2.0 * h[va]);
                (tex, u, v)
            }
            Surface::Sphere { radius, texture, .. } => {
                let n = p / *radius;
                let u = 0.5 + n.x.atan2(n.z) / std::f64::consts::TAU;
                let v = (-n.y).clamp(-1.0, 1.0).acos() / std::f64::consts::PI;
                (texture, u, v)
            }
        }
    }

    /// Gray radiance of a hit.
    #[inline]
    pub(crate) fn shade(&self, i: usize, dir: &Vector3<f64>, t: f64, aux: u8) -> f32 {
        let (tex, u, v) = self.surface_uv(i, dir, t, aux);
        tex.sample(u, v)
    }

    /// Gray and RGB radiance of a hit.
    #[inline]
    pub(crate) fn shade_rgb(&self, i: usize, dir: &Vector3<f64>, t: f64, aux: u8) -> (f32, [f32; 3]) {
        let (tex, u, v) = self.surface_uv(i, dir, t, aux);
        (tex.sample(u, v), tex.sample_rgb(u, v))
    }
}
