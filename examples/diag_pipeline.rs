//! Where the pipeline loses (issue 12's diagnosis): per bench scene, the pipeline's render
//! against the gather, and with its layers swapped for the exact ones (true foreground +
//! estimated background, and the reverse), all scored in sRGB PSNR against the traced truth.
//!
//! `cargo run --release --example diag_pipeline -- SEED SCENES SIZE` (defaults 3 20 128).
//! Environment: `REAL=1` feeds the realistic depth map, `FGSWAP=1` also swaps the foreground's
//! colour or disparity alone and prints its disparity error, `REGION=1` prints the fill
//! region's counts, `WORST=1` the largest errors, `FGERR=1` the foreground colour's largest
//! errors (α·|F - F_true|) with the pixel's photo and background values, `BGPART=1` the render
//! with the estimated background swapped for the true one on its soft, hidden or uncovered
//! pixels only, `DILATE=R` / `RADIUS=R` set `[inpaint] dilate` / `radius`, `KEEP_CUT=1` leaves cut
//! highlights uncompleted (`[inpaint] highlights = "excluded"`), `PM=1` the
//! exemplar fill (`[inpaint] method = "patchmatch"`),
//! `AT=X,Y` (with `REGION=1`) prints the region around a pixel, `CUT=1` lists each background highlight the matte cuts with its hidden light (true /
//! estimated), `TWIN=1` traces the scene without the highlights hidden behind full cover (same inputs) and
//! prints how far apart the two truths lie,
//! `NOMATTE=1` runs the pipeline without the matte (the depth split), `DUMP=DIR` writes sRGB PNGs of the inputs, layers and renders, `FIRST=I` starts at scene I.
use drbokeh::bench::run::score;
use drbokeh::bench::scenes::generate;
use drbokeh::bench::trace::{TraceSettings, trace_split};
use drbokeh::config::{Config, KernelChoice};
use drbokeh::render::{self, Kernel, Layer, Profile, RenderSettings};
use drbokeh::stages::background::BandReach;
use drbokeh::stages::depth::Disparity;
use drbokeh::{Focus, Image, Pipeline, Scene};

fn main() -> drbokeh::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let seed: u64 = args.get(1).map(|s| s.parse().unwrap()).unwrap_or(3);
    let n: usize = args.get(2).map(|s| s.parse().unwrap()).unwrap_or(20);
    let size: usize = args.get(3).map(|s| s.parse().unwrap()).unwrap_or(128);
    let mut sums = [0f64; 6];
    println!("case            kind   gather  pipe   tFG+eBG eFG+tBG exact  scatter");
    let first: usize = std::env::var("FIRST").ok().map(|s| s.parse().unwrap()).unwrap_or(0);
    for i in first..n {
        let sc = generate(seed, i, size, size, &[]);
        let planes = sc.trace_planes();
        let ts = TraceSettings::new(sc.blur, sc.focus, 256, seed ^ (i as u64) << 20);
        let (gt, _) = trace_split(&planes, &ts, sc.window(), &|_| {})?;
        let border = sc.max_coc.ceil() as usize;
        let inp = sc.inputs()?;
        let (blur, focus) = (sc.blur, sc.focus);
        let rend = |layers: &[Layer], occ: bool| -> drbokeh::Result<Image> {
            let lens = render::auto_lens(layers, blur, focus);
            render::render(
                layers,
                &RenderSettings {
                    blur,
                    focus,
                    lens,
                    occlusion: occ,
                    profile: Profile::Physical,
                    aperture: drbokeh::render::Aperture::DISC,
                },
                Kernel::Fast { quality: 2 },
            )
        };
        let mut cfg = Config::default();
        cfg.render.blur = Some(blur);
        cfg.render.kernel = KernelChoice::Fast;
        if let Ok(r) = std::env::var("RADIUS") {
            cfg.inpaint.radius = r.parse().unwrap();
        }
        if std::env::var("KEEP_CUT").is_ok() {
            cfg.inpaint.highlights = drbokeh::stages::background::HighlightSources::Excluded;
        }
        if std::env::var("PM").is_ok() {
            cfg.inpaint.method = drbokeh::stages::inpaint_onnx::InpaintMethod::PatchMatch;
        }
        if let Ok(d) = std::env::var("DILATE") {
            cfg.inpaint.dilate = d.parse().unwrap();
        }
        let depth_in = if std::env::var("REAL").is_ok() { inp.realistic_disparity.clone() } else { inp.disparity.clone() };
        let scene = Scene {
            rgb: inp.aif.clone(),
            disparity: Disparity { map: depth_in, z_range: None, filled_fraction: 0.0 },
            matte: if std::env::var("NOMATTE").is_ok() { None } else { Some(inp.matte.clone()) },
            encoding: drbokeh::PhotoEncoding::Linear,
        };
        let out = Pipeline::from_config(cfg)?.run(&scene, Focus::Disparity(focus))?;
        let est = &out.layers;
        if std::env::var("DBG").is_ok() {
            let hard: Vec<bool> = inp.matte.data.iter().map(|&a| a > 0.5).collect();
            let e = drbokeh::stages::depth_edges::measure(&scene.disparity.map, &hard, size, size);
            let r = drbokeh::stages::depth_edges::foreground_estimate(&scene.disparity.map, &inp.matte, &e, 5.0)?;
            let nv = r.as_ref().map(|(_, v)| v.iter().filter(|&&x| x).count()).unwrap_or(0);
            let nh = hard.iter().filter(|&&x| x).count();
            eprintln!("{} ramp {:?} valid {nv} of {nh}", sc.name, e);
        }
        if std::env::var("CUT").is_ok() && est.len() == 2 {
            // Each background highlight the matte cuts (some of its pixels under α > 0.02,
            // some not): its hidden light, true against the estimated background layer.
            let m = sc.margin as f32;
            let (tb, eb) = (&inp.two_layers[1].image().to_image(), &est[1].image().to_image());
            let lum = |img: &Image, i: usize| {
                let d = &img.data[i * 5..i * 5 + 3];
                0.2126 * d[0] + 0.7152 * d[1] + 0.0722 * d[2]
            };
            for hl in &sc.bg_highlights {
                let d = drbokeh::stages::highlight_completion::Disc { cx: hl.cx - m, cy: hl.cy - m, r: hl.r, rgb: [0.0; 3] };
                let (mut seen, mut hidden, mut t, mut e) = (0f32, 0f32, 0f32, 0f32);
                for y in 0..size {
                    for x in 0..size {
                        let a = d.coverage(x, y);
                        if a <= 0.0 {
                            continue;
                        }
                        let i = y * size + x;
                        if inp.matte.data[i] > 0.02 {
                            hidden += a;
                            t += lum(tb, i);
                            e += lum(eb, i);
                        } else {
                            seen += a;
                        }
                    }
                }
                if hidden > 0.0 && seen > 0.0 {
                    eprintln!(
                        "{} cut highlight ({:.1}, {:.1}) r {:.2}: seen {:.0}%, hidden light {t:.1} / {e:.1}",
                        sc.name,
                        d.cx,
                        d.cy,
                        d.r,
                        100.0 * seen / (seen + hidden)
                    );
                }
            }
        }
        if std::env::var("DISCS").is_ok() {
            let opts = drbokeh::stages::background::InpaintOptions::default();
            let r = drbokeh::stages::background::fill_region(&inp.aif, &inp.matte, &opts, 0.0, BandReach::Any);
            let mut f = inp.aif.clone();
            for d in drbokeh::stages::highlight_completion::complete(&mut f, &inp.aif, &r) {
                let m = sc.margin as f32;
                let near = sc
                    .bg_highlights
                    .iter()
                    .map(|h| (h.cx - m, h.cy - m, h.r, h.radiance * h.tint[1]))
                    .min_by(|a, b| ((a.0 - d.cx).hypot(a.1 - d.cy)).total_cmp(&(b.0 - d.cx).hypot(b.1 - d.cy)));
                eprintln!("{} disc ({:.2}, {:.2}) r {:.2} L {:.1}; nearest true {near:.2?}", sc.name, d.cx, d.cy, d.r, d.rgb[1]);
            }
        }
        if std::env::var("REGION").is_ok() {
            let r = drbokeh::stages::background::fill_region(
                &inp.aif,
                &inp.matte,
                &drbokeh::stages::background::InpaintOptions::default(),
                0.0,
                BandReach::Any,
            );
            eprintln!("{} band {} replaced {} highlights {}", sc.name, r.band, r.band_replaced, r.highlights_kept);
            if let Ok(at) = std::env::var("AT") {
                // The region around pixel X,Y: luminance, alpha, mask (M) and kept highlight (H).
                let v: Vec<usize> = at.split(',').map(|t| t.parse().unwrap()).collect();
                for y in v[1].saturating_sub(4)..(v[1] + 5).min(size) {
                    let row: Vec<String> = (v[0].saturating_sub(4)..(v[0] + 5).min(size))
                        .map(|x| {
                            let i = y * size + x;
                            let l = drbokeh::stages::highlights::luminance(&inp.aif.data[i * 3..i * 3 + 3]);
                            format!(
                                "{l:5.1}/{:.2}{}{}",
                                inp.matte.data[i],
                                if r.mask[i] { "M" } else { " " },
                                if r.highlights[i] { "H" } else { " " }
                            )
                        })
                        .collect();
                    eprintln!("  y{y:3} {}", row.join(" "));
                }
            }
            if let Ok(dir) = std::env::var("DUMP") {
                let buf: Vec<u8> = (0..size * size)
                    .flat_map(|i| {
                        [if r.highlights[i] { 255 } else { 0 }, if r.mask[i] { 255 } else { 0 }, (inp.matte.data[i] * 255.0) as u8]
                    })
                    .collect();
                image::RgbImage::from_raw(size as u32, size as u32, buf).unwrap().save(format!("{dir}/{}_region.png", sc.name)).unwrap();
            }
        }
        let p = |img: &Image| score(img, &gt, border).psnr_srgb;
        let g = p(&drbokeh::bench::gather::gather(&inp.aif, &inp.disparity, blur, focus));
        let pipe = p(&out.image);
        if std::env::var("WORST").is_ok() {
            let g_img = drbokeh::bench::gather::gather(&inp.aif, &inp.disparity, blur, focus);
            for (name, img) in [("pipe", &out.image), ("gather", &g_img)] {
                let mut errs: Vec<(f32, usize)> = (0..size * size)
                    .filter(|&i| {
                        let (x, y) = (i % size, i / size);
                        x >= border && y >= border && x < size - border && y < size - border
                    })
                    .map(|i| ((0..3).map(|k| (img.data[i * 3 + k] - gt.data[i * 3 + k]).powi(2)).sum::<f32>(), i))
                    .collect();
                errs.sort_by(|a, b| b.0.total_cmp(&a.0));
                let total: f32 = errs.iter().map(|e| e.0).sum();
                let top: Vec<String> = errs[..4]
                    .iter()
                    .map(|&(e, i)| {
                        format!(
                            "({},{}) e{:.1} v{:.2} gt{:.2} aif{:.2} a{:.2}",
                            i % size,
                            i / size,
                            e,
                            img.data[i * 3],
                            gt.data[i * 3],
                            inp.aif.data[i * 3],
                            inp.matte.data[i]
                        )
                    })
                    .collect();
                eprintln!("{} {name}: sse {total:.1} top {}", sc.name, top.join(" "));
            }
        }
        let (tf_eb, ef_tb) = if est.len() == 2 {
            (p(&rend(&[inp.two_layers[0].clone(), est[1].clone()], true)?), p(&rend(&[est[0].clone(), inp.two_layers[1].clone()], true)?))
        } else {
            (f64::NAN, f64::NAN)
        };
        let ex = p(&rend(&inp.two_layers, true)?);
        let (twin, removed) = sc.without_hidden_highlights();
        if std::env::var("TWIN").is_ok() && removed == 0 {
            eprintln!("{} twin: hidden highlights 0", sc.name);
        } else if std::env::var("TWIN").is_ok() {
            let tin = twin.inputs()?;
            assert!(tin.aif.data == inp.aif.data && tin.matte.data == inp.matte.data && tin.disparity.data == inp.disparity.data);
            let (gt2, _) = trace_split(&twin.trace_planes(), &ts, twin.window(), &|_| {})?;
            let apart = score(&gt2, &gt, border).psnr_srgb;
            let ex_twin = p(&rend(&tin.two_layers, true)?);
            let pipe2 = score(&out.image, &gt2, border).psnr_srgb;
            eprintln!(
                "{} twin: hidden highlights {removed}  truths apart {apart:.2}  exact {ex:.2} twin's exact layers {ex_twin:.2}  pipeline {pipe:.2} / on the twin {pipe2:.2}",
                sc.name
            );
        }
        if std::env::var("FGSWAP").is_ok() && est.len() == 2 {
            let t = &inp.two_layers[0];
            let e = &est[0];
            let n = size * size;
            let chan = |l: &Layer, c: usize| Image::from_vec(size, size, 1, (0..n).map(|i| l.image().data[i * 5 + c]).collect()).unwrap();
            let rgb_of = |l: &Layer| l.image().select_channels(&[0, 1, 2]);
            let true_rgb = Layer::from_parts(&rgb_of(t), &chan(e, 3), &chan(e, 4), "x")?;
            let true_d = Layer::from_parts(&rgb_of(e), &chan(e, 3), &chan(t, 4), "x")?;
            let a = p(&rend(&[true_rgb, inp.two_layers[1].clone()], true)?);
            let b = p(&rend(&[true_d, inp.two_layers[1].clone()], true)?);
            let (mut err, mut cnt, mut err_in, mut err_raw) = (0f64, 0usize, 0f64, 0f64);
            let first: usize = std::env::var("FIRST").ok().map(|s| s.parse().unwrap()).unwrap_or(0);
            for i in first..n {
                if inp.matte.data[i] >= 0.5 {
                    err += (e.image().data[i * 5 + 4] - t.image().data[i * 5 + 4]).abs() as f64;
                    err_in += (inp.disparity.data[i] - t.image().data[i * 5 + 4]).abs() as f64;
                    err_raw += (scene.disparity.map.data[i] - t.image().data[i * 5 + 4]).abs() as f64;
                    cnt += 1;
                }
            }
            let c = cnt.max(1) as f64;
            eprintln!(
                "{} fg swaps: true rgb {a:.2}  true disparity {b:.2}  fg disp MAE {:.4} (input map {:.4}, exact map {:.4})",
                sc.name,
                err / c,
                err_raw / c,
                err_in / c
            );
        }
        if std::env::var("BGPART").is_ok() && est.len() == 2 {
            let mix = |pick: &dyn Fn(f32) -> bool| -> drbokeh::Result<f64> {
                let (t, e) = (&inp.two_layers[1].image().to_image(), &est[1].image().to_image());
                let mut d = e.clone();
                for i in 0..size * size {
                    if pick(inp.matte.data[i]) {
                        d.data[i * 5..i * 5 + 5].copy_from_slice(&t.data[i * 5..i * 5 + 5]);
                    }
                }
                let l = Layer::new(d, "x")?;
                Ok(p(&rend(&[inp.two_layers[0].clone(), l], true)?))
            };
            let hl_only = {
                let (t, e) = (&inp.two_layers[1].image().to_image(), &est[1].image().to_image());
                let mut d = e.clone();
                for i in 0..size * size {
                    if inp.matte.data[i] > 0.0 && t.data[i * 5..i * 5 + 3].iter().any(|&v| v > 1.0) {
                        d.data[i * 5..i * 5 + 5].copy_from_slice(&t.data[i * 5..i * 5 + 5]);
                    }
                }
                p(&rend(&[inp.two_layers[0].clone(), Layer::new(d, "x")?], true)?)
            };
            eprintln!("{} bgpart: true HDR pixels behind the matte {hl_only:.2}", sc.name);
            let soft = mix(&|a| a > 0.0 && a < 0.98)?;
            let hidden = mix(&|a| a >= 0.98)?;
            let outside = mix(&|a| a <= 0.0)?;
            eprintln!("{} bgpart: true soft {soft:.2} true hidden {hidden:.2} true outside {outside:.2}", sc.name);
        }
        if std::env::var("FGERR").is_ok() && est.len() == 2 {
            let (tf, ef) = (&inp.two_layers[0].image().to_image(), &est[0].image().to_image());
            let (tb, eb) = (&inp.two_layers[1].image().to_image(), &est[1].image().to_image());
            // The five largest of (squared error, pixel), with the pixel's values (red channel).
            let worst = |what: &str, mut v: Vec<(f32, usize)>| {
                let tot: f32 = v.iter().map(|x| x.0).sum();
                v.sort_by(|a, b| b.0.total_cmp(&a.0));
                let top: Vec<String> = v[..5.min(v.len())]
                    .iter()
                    .map(|&(er, i)| {
                        let r = |img: &Image| img.data[i * img.channels];
                        format!(
                            "({},{}) e{er:.3} a{:.2} aif{:.2} fg {:.2}/{:.2} bg {:.2}/{:.2}",
                            i % size,
                            i / size,
                            inp.matte.data[i],
                            r(&inp.aif),
                            r(ef),
                            r(tf),
                            r(eb),
                            r(tb)
                        )
                    })
                    .collect();
                eprintln!("{} {what} sum {tot:.2} (estimated/true): {}", sc.name, top.join(" "));
            };
            let sq =
                |e: &Image, t: &Image, i: usize, s: f32| (0..3).map(|k| (s * (e.data[i * 5 + k] - t.data[i * 5 + k])).powi(2)).sum::<f32>();
            worst("fg colour α·err", (0..size * size).map(|i| (sq(ef, tf, i, inp.matte.data[i]), i)).collect());
            let soft = (0..size * size).filter(|&i| inp.matte.data[i] > 0.0 && inp.matte.data[i] < 0.98);
            worst("bg at soft pixels err", soft.map(|i| (sq(eb, tb, i, 1.0), i)).collect());
        }
        if let Ok(dir) = std::env::var("DUMP") {
            let save = |img: &Image, name: &str| {
                let s = drbokeh::bench::metrics::srgb(img);
                let s = &s;
                let c = img.channels;
                let buf: Vec<u8> = (0..img.width * img.height)
                    .flat_map(|i| (0..3).map(move |k| (s.data[i * c + if c == 1 { 0 } else { k }] * 255.0 + 0.5) as u8))
                    .collect();
                image::RgbImage::from_raw(img.width as u32, img.height as u32, buf)
                    .unwrap()
                    .save(format!("{dir}/{}_{name}.png", sc.name))
                    .unwrap();
            };
            save(&inp.aif, "aif");
            save(&inp.matte, "matte");
            save(&gt, "gt");
            save(&out.image, "pipe");
            if est.len() == 2 {
                let a: Vec<f32> = (0..size * size).map(|i| est[0].alpha(i)).collect();
                save(&Image::from_vec(size, size, 1, a).unwrap(), "est_alpha");
                save(&est[1].image().to_image(), "est_bg");
                save(&inp.two_layers[1].image().to_image(), "true_bg");
            }
        }
        let opaque = Image::filled(size, size, 1, 1.0);
        let sc1 = p(&rend(&[Layer::from_parts(&inp.aif, &opaque, &inp.disparity, "s")?], false)?);
        let v = [g, pipe, tf_eb, ef_tb, ex, sc1];
        for (s, x) in sums.iter_mut().zip(v) {
            *s += x;
        }
        println!(
            "{:<15} {:<6} {:6.2} {:6.2} {:6.2}  {:6.2}  {:6.2} {:6.2}  {}{}",
            sc.name,
            sc.focus_kind.name(),
            g,
            pipe,
            tf_eb,
            ef_tb,
            ex,
            sc1,
            if sc.thin { "thin " } else { "" },
            if sc.highlights { "hl" } else { "" }
        );
    }
    let m: Vec<String> = sums.iter().map(|s| format!("{:6.2}", s / (n - first) as f64)).collect();
    println!("mean                   {}", m.join(" "));
    Ok(())
}
