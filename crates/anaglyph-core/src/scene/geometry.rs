//! Scene geometry for the ray caster: 3-vectors, pinhole cameras on the array grid, and
//! exact ray intersections with textured rectangles, spheres and boxes.
//!
//! Frame: millimetres, x right, y down, z forward (the camera looks along +z), origin at
//! camera r0c0. A camera at grid position (row, col) sits at `(col·b_x, row·b_y, 0)`, so a
//! point at depth Z appears `k·f·b_x/Z` pixels further left in the camera k columns to the
//! right: the disparity convention of the simulator's truth.

use std::ops::{Add, Mul, Neg, Sub};

/// A 3-vector in mm.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Vec3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

impl Vec3 {
    pub const fn new(x: f64, y: f64, z: f64) -> Self {
        Vec3 { x, y, z }
    }
    pub fn dot(self, o: Vec3) -> f64 {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    pub fn cross(self, o: Vec3) -> Vec3 {
        Vec3::new(
            self.y * o.z - self.z * o.y,
            self.z * o.x - self.x * o.z,
            self.x * o.y - self.y * o.x,
        )
    }
    pub fn length(self) -> f64 {
        self.dot(self).sqrt()
    }
    pub fn normalized(self) -> Vec3 {
        self * (1.0 / self.length())
    }
}

impl Add for Vec3 {
    type Output = Vec3;
    fn add(self, o: Vec3) -> Vec3 {
        Vec3::new(self.x + o.x, self.y + o.y, self.z + o.z)
    }
}
impl Sub for Vec3 {
    type Output = Vec3;
    fn sub(self, o: Vec3) -> Vec3 {
        Vec3::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }
}
impl Mul<f64> for Vec3 {
    type Output = Vec3;
    fn mul(self, k: f64) -> Vec3 {
        Vec3::new(self.x * k, self.y * k, self.z * k)
    }
}
impl Neg for Vec3 {
    type Output = Vec3;
    fn neg(self) -> Vec3 {
        self * -1.0
    }
}

/// Rotation from Euler angles in degrees about x, then y, then z (`R = Rz·Ry·Rx`), as rows.
pub fn rotation(degrees: [f64; 3]) -> [Vec3; 3] {
    let [a, b, c] = degrees.map(f64::to_radians);
    let (sa, ca, sb, cb, sc, cc) = (a.sin(), a.cos(), b.sin(), b.cos(), c.sin(), c.cos());
    [
        Vec3::new(cc * cb, cc * sb * sa - sc * ca, cc * sb * ca + sc * sa),
        Vec3::new(sc * cb, sc * sb * sa + cc * ca, sc * sb * ca - cc * sa),
        Vec3::new(-sb, cb * sa, cb * ca),
    ]
}

/// `R · v` for a rotation given as rows.
pub fn rotate(r: &[Vec3; 3], v: Vec3) -> Vec3 {
    Vec3::new(r[0].dot(v), r[1].dot(v), r[2].dot(v))
}

/// A ray `origin + t·direction`, t > 0.
#[derive(Debug, Clone, Copy)]
pub struct Ray {
    pub origin: Vec3,
    pub direction: Vec3,
}

/// A pinhole camera: centre, orientation (camera-to-world rotation rows) and intrinsics.
#[derive(Debug, Clone)]
pub struct PinholeCamera {
    pub centre: Vec3,
    /// Camera-to-world rotation (identity for a rectified, parallel array).
    pub rotation: [Vec3; 3],
    pub focal_px: f64,
    pub width: usize,
    pub height: usize,
    /// The principal point's offset from the image centre, pixels (an array registered to
    /// a plane shifts each camera's image so that the plane has zero disparity).
    pub principal_offset_px: [f64; 2],
}

impl PinholeCamera {
    /// A camera of the parallel array at `[x, y]` mm in the array's plane (x right, y
    /// down, seen from behind the array).
    pub fn at_position(position_mm: [f64; 2], focal_px: f64, size: (usize, usize)) -> Self {
        PinholeCamera {
            centre: Vec3::new(position_mm[0], position_mm[1], 0.0),
            rotation: rotation([0.0; 3]),
            focal_px,
            width: size.0,
            height: size.1,
            principal_offset_px: [0.0; 2],
        }
    }

    /// The camera of an array registered to a plane at `plane_mm` (see
    /// [`crate::rig::RigFile::calibration_plane_mm`]), `from_reference_mm` away from the
    /// reference camera in the array's plane: the image shifted so that a point of the
    /// plane falls where the reference camera sees it, i.e. at zero disparity.
    pub fn registered_to_plane(self, from_reference_mm: [f64; 2], plane_mm: f64) -> Self {
        let shift = |mm: f64| self.focal_px * mm / plane_mm;
        PinholeCamera {
            principal_offset_px: from_reference_mm.map(shift),
            ..self
        }
    }

    /// The ray through image position `(x, y)` in pixels (pixel centres at +0.5), with the
    /// principal point at the image centre.
    pub fn ray(&self, x: f64, y: f64) -> Ray {
        let local = Vec3::new(
            x - 0.5 * self.width as f64 - self.principal_offset_px[0],
            y - 0.5 * self.height as f64 - self.principal_offset_px[1],
            self.focal_px,
        );
        Ray {
            origin: self.centre,
            direction: rotate(&self.rotation, local).normalized(),
        }
    }

    /// Image position of a world point, and its depth along the optical axis (None behind).
    pub fn project(&self, p: Vec3) -> Option<(f64, f64, f64)> {
        let d = p - self.centre;
        // World-to-camera is the transpose of the camera-to-world rotation.
        let r = &self.rotation;
        let local = Vec3::new(
            r[0].x * d.x + r[1].x * d.y + r[2].x * d.z,
            r[0].y * d.x + r[1].y * d.y + r[2].y * d.z,
            r[0].z * d.x + r[1].z * d.y + r[2].z * d.z,
        );
        (local.z > 0.0).then(|| {
            (
                self.focal_px * local.x / local.z
                    + 0.5 * self.width as f64
                    + self.principal_offset_px[0],
                self.focal_px * local.y / local.z
                    + 0.5 * self.height as f64
                    + self.principal_offset_px[1],
                local.z,
            )
        })
    }
}

/// Where a ray meets a surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray, mm.
    pub t: f64,
    /// Surface coordinates in mm (for texturing), from the shape's own origin.
    pub u: f64,
    pub v: f64,
    /// Which face of a box (0–5); 0 for other shapes.
    pub face: usize,
}

/// A surface the ray caster can hit.
#[derive(Debug, Clone)]
pub enum Shape {
    /// A rectangle: centre, unit axes `axis_u`, `axis_v` spanning it, half sizes in mm.
    Rectangle {
        centre: Vec3,
        axis_u: Vec3,
        axis_v: Vec3,
        half_u: f64,
        half_v: f64,
    },
    Sphere {
        centre: Vec3,
        radius: f64,
    },
    /// An oriented box: centre, rotation rows, half extents.
    Cuboid {
        centre: Vec3,
        rotation: [Vec3; 3],
        half: Vec3,
    },
}

/// Smallest ray parameter accepted (avoids self-hits at the origin).
const MIN_T: f64 = 1e-9;

impl Shape {
    /// A rectangle of `width × height` mm centred at `centre`, rotated by Euler angles
    /// (degrees); unrotated, it faces the cameras with u along +x and v along +y.
    pub fn rectangle(centre: Vec3, width: f64, height: f64, rotation_deg: [f64; 3]) -> Shape {
        let r = rotation(rotation_deg);
        Shape::Rectangle {
            centre,
            axis_u: rotate(&r, Vec3::new(1.0, 0.0, 0.0)),
            axis_v: rotate(&r, Vec3::new(0.0, 1.0, 0.0)),
            half_u: 0.5 * width,
            half_v: 0.5 * height,
        }
    }

    /// The nearest hit with `t > MIN_T`, if any.
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        match *self {
            Shape::Rectangle {
                centre,
                axis_u,
                axis_v,
                half_u,
                half_v,
            } => {
                let normal = axis_u.cross(axis_v);
                let denom = normal.dot(ray.direction);
                if denom.abs() < 1e-15 {
                    return None;
                }
                let t = normal.dot(centre - ray.origin) / denom;
                if t <= MIN_T {
                    return None;
                }
                let d = ray.origin + ray.direction * t - centre;
                let (u, v) = (d.dot(axis_u), d.dot(axis_v));
                (u.abs() <= half_u && v.abs() <= half_v).then_some(Hit {
                    t,
                    u: u + half_u,
                    v: v + half_v,
                    face: 0,
                })
            }
            Shape::Sphere { centre, radius } => {
                let oc = ray.origin - centre;
                let b = oc.dot(ray.direction);
                let c = oc.dot(oc) - radius * radius;
                let disc = b * b - c;
                if disc < 0.0 {
                    return None;
                }
                let root = disc.sqrt();
                let t = if -b - root > MIN_T {
                    -b - root
                } else {
                    -b + root
                };
                if t <= MIN_T {
                    return None;
                }
                let n = (ray.origin + ray.direction * t - centre) * (1.0 / radius);
                // Longitude/latitude arc lengths on the sphere, mm.
                let u = n.x.atan2(-n.z) * radius + std::f64::consts::PI * radius;
                let v = n.y.clamp(-1.0, 1.0).asin() * radius + 0.5 * std::f64::consts::PI * radius;
                Some(Hit { t, u, v, face: 0 })
            }
            Shape::Cuboid {
                centre,
                rotation: r,
                half,
            } => {
                // Slab test in the box frame.
                let to_local = |v: Vec3| {
                    Vec3::new(
                        r[0].x * v.x + r[1].x * v.y + r[2].x * v.z,
                        r[0].y * v.x + r[1].y * v.y + r[2].y * v.z,
                        r[0].z * v.x + r[1].z * v.y + r[2].z * v.z,
                    )
                };
                let o = to_local(ray.origin - centre);
                let d = to_local(ray.direction);
                let (mut t_near, mut t_far, mut axis_near, mut axis_far) =
                    (f64::NEG_INFINITY, f64::INFINITY, 0usize, 0usize);
                for (axis, (oa, da, ha)) in
                    [(o.x, d.x, half.x), (o.y, d.y, half.y), (o.z, d.z, half.z)]
                        .into_iter()
                        .enumerate()
                {
                    if da.abs() < 1e-15 {
                        if oa.abs() > ha {
                            return None;
                        }
                        continue;
                    }
                    let (mut t0, mut t1) = ((-ha - oa) / da, (ha - oa) / da);
                    if t0 > t1 {
                        std::mem::swap(&mut t0, &mut t1);
                    }
                    if t0 > t_near {
                        t_near = t0;
                        axis_near = axis;
                    }
                    if t1 < t_far {
                        t_far = t1;
                        axis_far = axis;
                    }
                }
                if t_near > t_far {
                    return None;
                }
                let (t, axis) = if t_near > MIN_T {
                    (t_near, axis_near)
                } else {
                    (t_far, axis_far)
                };
                if t <= MIN_T {
                    return None;
                }
                let p = o + d * t;
                let coords = [p.x, p.y, p.z];
                let halves = [half.x, half.y, half.z];
                let face = 2 * axis + usize::from(coords[axis] > 0.0);
                let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
                Some(Hit {
                    t,
                    u: coords[a] + halves[a],
                    v: coords[b] + halves[b],
                    face,
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_projects_with_the_array_disparity() {
        let (f, bx, by, z) = (1800.0, 30.0, 50.0, 2000.0);
        let point = Vec3::new(123.0, -45.0, z);
        let on_grid = |row: usize, col: usize| {
            PinholeCamera::at_position([col as f64 * bx, row as f64 * by], f, (640, 480))
        };
        let reference = on_grid(0, 0);
        let (x0, y0, depth) = reference.project(point).unwrap();
        assert!((depth - z).abs() < 1e-9);
        let d = f * bx / z;
        for (row, col) in [(0, 1), (0, 3), (1, 0), (1, 2)] {
            let cam = on_grid(row, col);
            let (x, y, _) = cam.project(point).unwrap();
            assert!((x - (x0 - col as f64 * d)).abs() < 1e-9);
            assert!((y - (y0 - row as f64 * d * by / bx)).abs() < 1e-9);
        }
        // The ray through a projection meets the point.
        let ray = reference.ray(x0, y0);
        let t = (point - ray.origin).length();
        assert!((ray.origin + ray.direction * t - point).length() < 1e-9);
    }

    #[test]
    fn an_array_registered_to_a_plane_sees_it_at_zero_disparity() {
        let (f, bx, by, plane) = (1800.0, 30.0, 50.0, 1500.0);
        let camera = |row: usize, col: usize| {
            let at = [col as f64 * bx, row as f64 * by];
            PinholeCamera::at_position(at, f, (640, 480)).registered_to_plane(at, plane)
        };
        let d_plane = f * bx / plane;
        for z in [plane, 1000.0, 3000.0] {
            let point = Vec3::new(40.0, 25.0, z);
            let (x0, y0, _) = camera(0, 0).project(point).unwrap();
            // Column-step disparity relative to the plane: 0 on it, > 0 nearer, < 0 beyond.
            let d = f * bx / z - d_plane;
            for (row, col) in [(0, 1), (1, 2), (2, 2)] {
                let (x, y, _) = camera(row, col).project(point).unwrap();
                assert!((x - (x0 - col as f64 * d)).abs() < 1e-9, "z {z}");
                assert!((y - (y0 - row as f64 * d * by / bx)).abs() < 1e-9, "z {z}");
                // The ray through the projection meets the point.
                let ray = camera(row, col).ray(x, y);
                let t = (point - ray.origin).length();
                assert!((ray.origin + ray.direction * t - point).length() < 1e-9);
            }
        }
    }

    #[test]
    fn intersections_match_closed_forms() {
        let ray = Ray {
            origin: Vec3::default(),
            direction: Vec3::new(0.0, 0.0, 1.0),
        };
        let wall = Shape::rectangle(Vec3::new(0.0, 0.0, 1000.0), 400.0, 300.0, [0.0; 3]);
        let hit = wall.intersect(&ray).unwrap();
        assert!(
            (hit.t - 1000.0).abs() < 1e-9
                && (hit.u - 200.0).abs() < 1e-9
                && (hit.v - 150.0).abs() < 1e-9
        );
        // Slanted 60° about y: still hit at the centre, at the same depth.
        let slanted = Shape::rectangle(Vec3::new(0.0, 0.0, 1000.0), 400.0, 300.0, [0.0, 60.0, 0.0]);
        assert!((slanted.intersect(&ray).unwrap().t - 1000.0).abs() < 1e-9);
        let off = Ray {
            origin: Vec3::new(250.0, 0.0, 0.0),
            direction: Vec3::new(0.0, 0.0, 1.0),
        };
        assert!(wall.intersect(&off).is_none());

        let ball = Shape::Sphere {
            centre: Vec3::new(0.0, 0.0, 500.0),
            radius: 100.0,
        };
        assert!((ball.intersect(&ray).unwrap().t - 400.0).abs() < 1e-9);
        let tangent = Ray {
            origin: Vec3::new(100.0 + 1e-6, 0.0, 0.0),
            direction: Vec3::new(0.0, 0.0, 1.0),
        };
        assert!(ball.intersect(&tangent).is_none());

        let cube = Shape::Cuboid {
            centre: Vec3::new(0.0, 0.0, 800.0),
            rotation: rotation([0.0, 45.0, 0.0]),
            half: Vec3::new(50.0, 50.0, 50.0),
        };
        // Rotated 45° about y, the nearest point on the axis is the vertical edge: 800 − 50√2.
        assert!((cube.intersect(&ray).unwrap().t - (800.0 - 50.0 * 2f64.sqrt())).abs() < 1e-9);
        let behind = Ray {
            origin: Vec3::new(0.0, 0.0, 2000.0),
            direction: Vec3::new(0.0, 0.0, 1.0),
        };
        assert!(
            cube.intersect(&behind).is_none()
                && ball.intersect(&behind).is_none()
                && wall.intersect(&behind).is_none()
        );
    }

    #[test]
    fn rotations_are_orthonormal() {
        let r = rotation([10.0, -20.0, 30.0]);
        for i in 0..3 {
            for j in 0..3 {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((r[i].dot(r[j]) - want).abs() < 1e-12);
            }
        }
        let v = rotate(&rotation([0.0, 0.0, 90.0]), Vec3::new(1.0, 0.0, 0.0));
        assert!((v - Vec3::new(0.0, 1.0, 0.0)).length() < 1e-12);
    }
}
