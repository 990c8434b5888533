//! Where the pipeline loses on a ground-truth folder (`shared/groundtruth` format, e.g. the
//! held-out Mitsuba scenes): per setting, the pipeline at the tool's defaults, the exact
//! layers, and the pipeline's layers with the true background or the true foreground swapped
//! in, scored in sRGB PSNR against the traced truth; `DUMP=DIR` writes sRGB PNGs of the truth,
//! the pipeline's render and its squared-error map.
//!
//! `HL=1` adds the true background's highlights (luminance > 2) under the matte against the
//! estimate, and the render with them swapped in (all of them, or only those no pixel of the
//! photo shows); `BLOBS=1` lists them one by one; `BANDS=1` sums the squared error by distance
//! to the solid matte.
//!
//! `INPUT=srgb8|srgb8-psf` feeds the pipeline the bench's 8-bit photo instead of the linear
//! one (`HIGHLIGHTS=off` turns its highlights stage off).
//!
//! `cargo run --release --example diag_groundtruth -- SCENE_DIR...`
use drbokeh::bench::groundtruth::GtScene;
use drbokeh::bench::inputs::{Input, prepare};
use drbokeh::bench::metrics::srgb;
use drbokeh::bench::run::score;
use drbokeh::bench::scenes::SceneInputs;
use drbokeh::config::{Config, KernelChoice};
use drbokeh::render::{self, Kernel, Layer, Profile, RenderSettings};
use drbokeh::stages::depth::Disparity;
use drbokeh::{Focus, Image, Pipeline, Scene};

fn save(img: &Image, path: &str) {
    let s = srgb(img);
    let c = img.channels;
    let buf: Vec<u8> = (0..img.width * img.height)
        .flat_map(|i| (0..3).map(|k| (s.data[i * c + if c == 1 { 0 } else { k }] * 255.0 + 0.5) as u8).collect::<Vec<_>>())
        .collect();
    image::RgbImage::from_raw(img.width as u32, img.height as u32, buf).expect("size").save(path).expect("write");
}

fn main() -> drbokeh::Result<()> {
    println!("scene            setting    pipe   exact  eFG+tBG tFG+eBG");
    for dir in std::env::args().skip(1) {
        let sc = GtScene::load(std::path::Path::new(&dir))?;
        let exact = sc.exact_layers()?;
        for s in &sc.settings {
            let border = s.coc_max.ceil() as usize;
            let (blur, focus) = (s.blur, s.focus);
            let rend = |layers: &[Layer]| -> drbokeh::Result<Image> {
                let lens = render::auto_lens(layers, blur, focus);
                let rs = RenderSettings {
                    blur,
                    focus,
                    lens,
                    occlusion: true,
                    profile: Profile::Physical,
                    aperture: drbokeh::render::Aperture::DISC,
                };
                render::render(layers, &rs, Kernel::Fast { quality: 2 })
            };
            let mut cfg = Config::default();
            cfg.render.blur = Some(blur);
            cfg.render.kernel = KernelChoice::Fast;
            if std::env::var("HIGHLIGHTS").is_ok_and(|v| v == "off") {
                cfg.highlights.mode = drbokeh::stages::light_recovery::HighlightMode::Off;
            }
            let input = std::env::var("INPUT").ok().and_then(|v| Input::parse(&v)).unwrap_or(Input::Linear);
            let linear = SceneInputs {
                aif: sc.aif.clone(),
                disparity: sc.disparity.clone(),
                matte: sc.alpha.clone(),
                realistic_disparity: sc.disparity.clone(),
                two_layers: exact.clone(),
                plane_layers: Vec::new(),
            };
            let photo = prepare(&linear, input)?.scene.aif.clone();
            let scene = Scene {
                rgb: photo,
                disparity: Disparity { map: sc.disparity.clone(), z_range: None, filled_fraction: 0.0 },
                matte: Some(sc.alpha.clone()),
                encoding: input.encoding(),
            };
            let out = Pipeline::from_config(cfg)?.run(&scene, Focus::Disparity(focus))?;
            let p = |img: &Image| score(img, &s.gt, border).psnr_srgb;
            let (ef_tb, tf_eb) = if out.layers.len() == 2 {
                (p(&rend(&[out.layers[0].clone(), exact[1].clone()])?), p(&rend(&[exact[0].clone(), out.layers[1].clone()])?))
            } else {
                (f64::NAN, f64::NAN)
            };
            println!("{:<16} {:<9} {:6.2} {:6.2} {:6.2}  {:6.2}", sc.name, s.name, p(&out.image), p(&rend(&exact)?), ef_tb, tf_eb);
            if std::env::var("HL").is_ok() && out.layers.len() == 2 {
                // True background highlights (luminance > 2) under the matte, against the
                // pipeline's background layer there.
                let (w, tb, eb) = (sc.aif.width, &exact[1], &out.layers[1]);
                let lum = |l: &Layer, i: usize| {
                    let d = &l.image().data[i * 5..i * 5 + 3];
                    0.2126 * d[0] + 0.7152 * d[1] + 0.0722 * d[2]
                };
                let (mut n, mut got, mut want) = (0, 0f64, 0f64);
                for i in 0..w * sc.aif.height {
                    if sc.alpha.data[i] > 0.02 && lum(tb, i) > 2.0 {
                        n += 1;
                        want += lum(tb, i) as f64;
                        got += lum(eb, i) as f64;
                    }
                }
                let mut unseen = vec![false; w * sc.aif.height];
                {
                    // Each true highlight (8-connected, luminance > 2) with a pixel under the
                    // matte: its visible and hidden pixels, and the hidden light true / estimated.
                    let hh = sc.aif.height;
                    let bright: Vec<bool> = (0..w * hh).map(|i| lum(tb, i) > 2.0).collect();
                    let mut seen = vec![false; w * hh];
                    for st in 0..w * hh {
                        if !bright[st] || seen[st] {
                            continue;
                        }
                        let mut comp = vec![st];
                        seen[st] = true;
                        let mut k = 0;
                        while k < comp.len() {
                            let i = comp[k];
                            k += 1;
                            let (x, y) = ((i % w) as isize, (i / w) as isize);
                            for dy in -1..=1isize {
                                for dx in -1..=1isize {
                                    let (xx, yy) = (x + dx, y + dy);
                                    if xx >= 0 && yy >= 0 && (xx as usize) < w && (yy as usize) < hh {
                                        let j = yy as usize * w + xx as usize;
                                        if bright[j] && !seen[j] {
                                            seen[j] = true;
                                            comp.push(j);
                                        }
                                    }
                                }
                            }
                        }
                        let hidden: Vec<usize> = comp.iter().copied().filter(|&i| sc.alpha.data[i] > 0.02).collect();
                        if hidden.is_empty() {
                            continue;
                        }
                        let vis = comp.len() - hidden.len();
                        if vis == 0 {
                            comp.iter().for_each(|&i| unseen[i] = true);
                        }
                        if std::env::var("BLOBS").is_err() {
                            continue;
                        }
                        let (t, e): (f32, f32) =
                            hidden.iter().map(|&i| (lum(tb, i), lum(eb, i))).fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
                        let soft = hidden.iter().filter(|&&i| sc.alpha.data[i] < 0.98).count();
                        println!(
                            "      blob at ({}, {}): {} px visible, {} under the matte ({} soft); hidden light {t:.1} / {e:.1}",
                            comp[0] % w,
                            comp[0] / w,
                            vis,
                            hidden.len(),
                            soft
                        );
                    }
                }
                let mut swapped = eb.image().to_image();
                for i in 0..w * sc.aif.height {
                    if sc.alpha.data[i] > 0.02 && lum(tb, i) > 2.0 {
                        swapped.data[i * 5..i * 5 + 5].copy_from_slice(&tb.image().data[i * 5..i * 5 + 5]);
                    }
                }
                let with_true = score(&rend(&[out.layers[0].clone(), Layer::new(swapped, "x")?])?, &s.gt, border).psnr_srgb;
                let mut swapped = eb.image().to_image();
                for i in (0..w * sc.aif.height).filter(|&i| unseen[i]) {
                    swapped.data[i * 5..i * 5 + 5].copy_from_slice(&tb.image().data[i * 5..i * 5 + 5]);
                }
                let with_unseen = score(&rend(&[out.layers[0].clone(), Layer::new(swapped, "x")?])?, &s.gt, border).psnr_srgb;
                println!("    with the true hidden highlights {with_true:.2}; with only those no photo pixel shows {with_unseen:.2}");
                println!(
                    "    hidden highlight px {n}: true light {want:.1}, estimated {got:.1}; completed {}",
                    out.report
                        .stages
                        .iter()
                        .find(|s| s.name == "inpaint")
                        .and_then(|s| s.detail.as_ref())
                        .map_or(serde_json::Value::Null, |d| d["highlights_completed"].clone())
                );
            }
            if std::env::var("BANDS").is_ok() {
                // Squared sRGB error summed by distance (px, Chebyshev, capped at 40) to the
                // nearest pixel the matte covers fully, for the pipeline and the exact layers.
                let (w, h) = (sc.aif.width, sc.aif.height);
                let solid: Vec<bool> = sc.alpha.data.iter().map(|&a| a >= 0.98).collect();
                let dist = |x: usize, y: usize| -> usize {
                    for r in 0..40usize {
                        let (x0, x1, y0, y1) = (x.saturating_sub(r), (x + r).min(w - 1), y.saturating_sub(r), (y + r).min(h - 1));
                        if (y0..=y1).any(|yy| (x0..=x1).any(|xx| solid[yy * w + xx])) {
                            return r;
                        }
                    }
                    40
                };
                let ex = rend(&exact)?;
                let (a, b, g) = (srgb(&out.image), srgb(&ex), srgb(&s.gt));
                let mut bands = [[0f64; 2]; 6];
                let edges = [0usize, 1, 4, 10, 20, 40];
                for y in border..h - border {
                    for x in border..w - border {
                        let d = dist(x, y);
                        let k = edges.iter().rposition(|&e| d >= e).unwrap_or(0);
                        let i = (y * w + x) * 3;
                        for c in 0..3 {
                            bands[k][0] += ((a.data[i + c] - g.data[i + c]) as f64).powi(2);
                            bands[k][1] += ((b.data[i + c] - g.data[i + c]) as f64).powi(2);
                        }
                    }
                }
                let line: Vec<String> = edges.iter().zip(&bands).map(|(e, b)| format!(">={e}px {:.3}/{:.3}", b[0], b[1])).collect();
                println!("    squared error by distance to the solid matte, pipeline/exact: {}", line.join("  "));
            }
            if let Ok(d) = std::env::var("DUMP") {
                let stem = format!("{d}/{}_{}", sc.name, s.name);
                save(&s.gt, &format!("{stem}_gt.png"));
                save(&out.image, &format!("{stem}_pipe.png"));
                for (k, l) in out.layers.iter().enumerate() {
                    save(&l.image().to_image(), &format!("{stem}_layer{k}.png"));
                }
                let (a, b) = (srgb(&out.image), srgb(&s.gt));
                let err: Vec<f32> = a
                    .data
                    .chunks_exact(3)
                    .zip(b.data.chunks_exact(3))
                    .map(|(x, y)| x.iter().zip(y).map(|(u, v)| (u - v).powi(2)).sum::<f32>())
                    .collect();
                let peak = err.iter().copied().fold(1e-12, f32::max);
                let map = Image::from_vec(a.width, a.height, 1, err.iter().map(|e| (e / peak).sqrt()).collect()).expect("size");
                save(&map, &format!("{stem}_err.png"));
            }
        }
    }
    Ok(())
}
