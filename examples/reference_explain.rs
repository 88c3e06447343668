//! Why the reference differs from the exact truth on a built-in mesh scene (noise-free, exact
//! registration): for the points with the largest errors, every ray of the reference beside
//! the same ray cast at the exact mesh, counted by what stopped it.
//!
//! ```text
//! cargo run --release --example reference_explain -- SCENE [key=value ...]
//!   keys: width=180 height=90 model=equirect|perspective tmax=inf rays=64 worst=200 scan=-1
//!         region=X0,X1,Y0,Y1,Z0,Z1 (only points inside, world coordinates)
//! ```

use mvao::io::dataset::{Dataset, PlaceOptions};
use mvao::synth::{self, MeshKind, MeshScene, MeshSource, SynthOptions};
use mvao::testing::projection::SensorModel;
use mvao::testing::reference::{self as reference, RefParams, Scene};
use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let kind = MeshKind::from_name(args.first().map(String::as_str).unwrap_or("colonnade"))
        .ok_or_else(|| anyhow::anyhow!("unknown scene"))?;
    let kv: HashMap<String, String> = args[1..]
        .iter()
        .filter_map(|a| a.split_once('=').map(|(k, v)| (k.into(), v.into())))
        .collect();
    let get = |k: &str, d: &str| kv.get(k).cloned().unwrap_or_else(|| d.to_string());
    let tmax = match get("tmax", "inf").as_str() {
        "inf" => f32::INFINITY,
        t => t.parse::<f32>()?,
    };
    let rays: u32 = get("rays", "64").parse()?;
    let worst: usize = get("worst", "200").parse()?;
    let only: i64 = get("scan", "-1").parse()?;
    let model = match get("model", "equirect").as_str() {
        "perspective" => SensorModel::Perspective,
        _ => SensorModel::Equirect,
    };
    let out = PathBuf::from(get("out", "/tmp/mvao-reference-explain"));
    let _ = std::fs::remove_dir_all(&out);
    let sum = synth::run(&SynthOptions {
        mesh: Some(MeshSource::Builtin(kind)),
        stations: 3,
        model,
        width: get("width", "180").parse()?,
        height: get("height", "90").parse()?,
        seed: 1,
        noise: get("noise", "0").parse()?,
        normals: get("normals", "1") != "0",
        registration: mvao::synth::Registration {
            translation: get("reg", "0,0").split(',').next().unwrap_or("0").parse()?,
            angle_deg: get("reg", "0,0").split(',').nth(1).unwrap_or("0").parse()?,
        },
        out_dir: out.clone(),
        reference: Some(RefParams {
            rays,
            tmax,
            ..Default::default()
        }),
        ..SynthOptions::default()
    })?;
    let files: Vec<PathBuf> = sum.files.iter().map(|f| f.path.clone()).collect();
    let place = PlaceOptions {
        align: Some(sum.alignment.clone()),
        ..PlaceOptions::default()
    };
    let ds = Dataset::open(&files, &place, &|| {})?;
    let mut b = Scene::builder(ds.scans[0].pose);
    let mut geo = Vec::new();
    for s in &ds.scans {
        let setup = mvao::testing::sensor::setup(s, Default::default())?;
        let (normals, rad, _) = mvao::testing::view::scan_normals(s, &setup);
        let radii = reference::surfel_radii(s, &normals, &rad)?;
        b.add_surfels(&s.name, s.pose, &s.points, &normals, &radii)?;
        geo.push((normals, radii));
    }
    let scene = b.build();
    if let Some(q) = kv.get("find") {
        let v: Vec<f32> = q.split(',').map(|x| x.parse().unwrap_or(0.0)).collect();
        let c = glam::Vec3::new(v[0], v[1], v[2]);
        for (s, (normals, radii)) in ds.scans.iter().zip(&geo) {
            let (pts, _) = scene.to_frame(s.pose, &s.points, normals)?;
            let g = s.grid.as_ref().unwrap();
            for (i, p) in pts.iter().enumerate() {
                if p.distance(c) < 1e-3 {
                    println!(
                        "{} point {i} row {} col {} r={} n={:?}",
                        s.name, g.row[i], g.col[i], radii[i], normals[i]
                    );
                    for (j, q) in pts.iter().enumerate() {
                        let (dr, dc) = (
                            g.row[j] as i64 - g.row[i] as i64,
                            g.col[j] as i64 - g.col[i] as i64,
                        );
                        if dr.abs() <= 2 && dc.abs() <= 2 {
                            let l = s.points[j];
                            let e = (l - s.points[i]).normalize_or_zero();
                            let v = ((l + s.points[i]) * 0.5).normalize_or_zero();
                            println!(
                                "   ({dr},{dc}) local {:?} range {:.3} n={:?} edge-los {:.2}deg",
                                l,
                                l.length(),
                                normals[j],
                                e.dot(v).abs().acos().to_degrees()
                            );
                            let _ = q;
                        }
                    }
                }
            }
        }
        return Ok(());
    }
    let frame = scene.frame();
    let mesh = MeshScene::new(&kind.mesh());
    let lift = 1e-9 * mesh.extent();
    let prm = RefParams {
        rays,
        tmax,
        falloff: Default::default(),
        seed: 0,
    };
    let reach = if tmax.is_finite() {
        tmax as f64
    } else {
        f64::INFINITY
    };
    let mut tally: BTreeMap<String, (usize, f64)> = BTreeMap::new();
    let (mut sum_err, mut count) = (0.0f64, 0usize);
    let mut shown = 0;
    for (si, (s, (normals, radii))) in ds.scans.iter().zip(&geo).enumerate() {
        if only >= 0 && only as usize != si {
            continue;
        }
        let (pts, nrm) = scene.to_frame(s.pose, &s.points, normals)?;
        let a = reference::obscurance(&scene, &pts, &nrm, radii, &prm, &|_| {})?;
        // Truth per point with the same directions.
        let mut errs: Vec<(f32, usize)> = Vec::with_capacity(pts.len());
        let truth_of = |i: usize, dirs: &[glam::Vec3]| -> Vec<Option<f64>> {
            let pw = frame.transform_point3(pts[i].as_dvec3());
            let Some((q, prim)) = mesh.nearest(pw, 1.0) else {
                return vec![None; dirs.len()];
            };
            let nm = mesh.normal(prim as usize);
            let nm = if nm.dot(glam::DMat3::from_mat4(frame) * nrm[i].as_dvec3()) < 0.0 {
                -nm
            } else {
                nm
            };
            let o = q + nm * lift;
            dirs.iter()
                .map(|d| {
                    let dw = (glam::DMat3::from_mat4(frame) * d.as_dvec3()).normalize();
                    mesh.intersect_skip(o, dw, 0.0, reach, prim).map(|h| h.t)
                })
                .collect()
        };
        // Quick truth A for every point from the same directions (via explain's dirs would be
        // slow: use the fast reference dirs by explaining only the worst).
        let truth_file = out.join("reference-mesh");
        let t = if truth_file.exists() {
            mvao::accuracy::read_ao(&mvao::accuracy::reference_path(&truth_file, &s.name))?
        } else {
            Vec::new()
        };
        if t.is_empty() {
            // No truth file: rank by a cheap stand-in, A itself.
            for (i, v) in a.iter().enumerate() {
                errs.push((1.0 - v, i));
            }
        } else {
            for i in 0..pts.len() {
                errs.push(((a[i] - t[i]).abs(), i));
            }
        }
        if let Some(q) = kv.get("region") {
            // Only points whose world position lies in `x0,x1,y0,y1,z0,z1`.
            let b: Vec<f64> = q.split(',').map(str::parse).collect::<Result<_, _>>()?;
            anyhow::ensure!(b.len() == 6, "region=X0,X1,Y0,Y1,Z0,Z1 takes six numbers");
            errs.retain(|&(_, i)| {
                let w = frame.transform_point3(pts[i].as_dvec3());
                (b[0]..=b[1]).contains(&w.x)
                    && (b[2]..=b[3]).contains(&w.y)
                    && (b[4]..=b[5]).contains(&w.z)
            });
        }
        errs.sort_by(|x, y| y.0.total_cmp(&x.0));
        for &(_, i) in errs.iter().take(worst) {
            let acc = scene.explain(pts[i], nrm[i], radii[i], &prm, i as u64);
            let dirs: Vec<glam::Vec3> = acc.iter().map(|r| r.dir).collect();
            let tr = truth_of(i, &dirs);
            let n = nrm[i];
            let cls = if n.z > 0.9 {
                "up"
            } else if n.z < -0.9 {
                "down"
            } else {
                "side"
            };
            let sign_ok = match get("detail", "0").as_str() {
                "dark" => a[i] < t.get(i).copied().unwrap_or(1.0),
                "bright" => a[i] > t.get(i).copied().unwrap_or(1.0),
                "0" => false,
                _ => true,
            };
            let cls_want = get("cls", "any");
            let n0 = nrm[i];
            let cls0 = if n0.z > 0.9 {
                "up"
            } else if n0.z < -0.9 {
                "down"
            } else {
                "side"
            };
            if sign_ok && (cls_want == "any" || cls_want == cls0) && shown < 4 {
                shown += 1;
                println!(
                    "point {i} scan {si} p={:?} n={:?} r={:.3} A={:.3} truth={:.3}",
                    pts[i],
                    nrm[i],
                    radii[i],
                    a[i],
                    t.get(i).copied().unwrap_or(-1.0)
                );
                for (r, tt) in acc.iter().zip(&tr) {
                    if let Some(st) = r.stop {
                        if tt.is_none() || (tt.unwrap() as f32) > st.t * 1.5 {
                            println!(
                                "   d={:?} t={:.3} c={:?} n={:?} rad={:.3} tri={} truth={:?}",
                                r.dir, st.t, st.centre, st.normal, st.radius, st.triangle, tt
                            );
                        }
                    }
                }
            }
            for (r, tt) in acc.iter().zip(&tr) {
                let elev = r.dir.dot(n);
                let eb = if elev < 0.1 {
                    "el<0.1"
                } else if elev < 0.3 {
                    "el<0.3"
                } else {
                    "el>0.3"
                };
                let rho_ref = r.stop.map_or(1.0, |st| prm.falloff.rho(st.t, tmax));
                let rho_tru = tt.map_or(1.0, |d| prm.falloff.rho(d as f32, tmax));
                let diff = (rho_ref - rho_tru) as f64;
                if diff.abs() < 0.05 {
                    continue;
                }
                let key = match r.stop {
                    Some(st) if diff < 0.0 => {
                        let hit = r.dir * st.t + pts[i];
                        let hw = frame.transform_point3(hit.as_dvec3());
                        let off = mesh
                            .nearest(hw, 10.0)
                            .map_or(9.0, |(q, _)| (q - hw).length());
                        let same = st.normal.dot(n).abs() > 0.95
                            && n.dot(st.centre - pts[i]).abs()
                                < 0.05 * (st.centre - pts[i]).length();
                        let what = if same {
                            "coplanar"
                        } else if off > 0.25 * st.radius as f64 + 1e-4 {
                            "offmesh"
                        } else {
                            "onmesh"
                        };
                        let tb = if st.t < 4.0 * radii[i] {
                            "t<4r"
                        } else if st.t < 1.0 {
                            "t<1m"
                        } else {
                            "t>1m"
                        };
                        let truth = match tt {
                            Some(d) => format!("truth@{:.1}", d.min(99.0)),
                            None => "truth-miss".into(),
                        };
                        let _ = truth;
                        format!("{cls} DARK {what} {tb} {eb} disc={}", r.discarded.min(1))
                    }
                    _ => {
                        let tb = match tt {
                            Some(d) if *d < 1.0 => "truth<1m",
                            Some(d) if *d < 5.0 => "truth<5m",
                            Some(_) => "truth>5m",
                            None => "none",
                        };
                        format!(
                            "{cls} BRIGHT {} {tb} {eb} disc={}",
                            if r.stop.is_some() {
                                "farther"
                            } else {
                                "escaped"
                            },
                            r.discarded.min(1)
                        )
                    }
                };
                let e = tally.entry(key).or_default();
                e.0 += 1;
                e.1 += diff / rays as f64;
            }
            sum_err += (a[i] - t.get(i).copied().unwrap_or(1.0)) as f64;
            count += 1;
        }
    }
    println!(
        "{count} worst points, mean signed error {:.4}",
        sum_err / count.max(1) as f64
    );
    let mut v: Vec<_> = tally.into_iter().collect();
    v.sort_by(|x, y| x.1 .1.abs().total_cmp(&y.1 .1.abs()).reverse());
    for (k, (c, e)) in v.iter().take(40) {
        println!("{:>7} rays  {:+.4} per pt  {k}", c, e / count.max(1) as f64);
    }
    Ok(())
}
