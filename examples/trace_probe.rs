use drbokeh::bench::groundtruth::GtScene;
use drbokeh::bench::metrics::{psnr, rmse};
use drbokeh::bench::scenes::gt_plane_layers;
use drbokeh::bench::trace::{trace, Plane, TraceSettings, Footprint, Window};
use drbokeh::color::linear_to_srgb;
use std::time::Instant;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let spp: u32 = args[1].parse().unwrap();
    let tex = if args[2] == "box" { Footprint::Sampled } else { Footprint::Analytic };
    let only: Option<&str> = args.get(3).map(|s| s.as_str());
    for name in ["portrait", "thin_bars"] {
        let sc = GtScene::load(std::path::Path::new(&format!("../shared/groundtruth/{name}"))).unwrap();
        let layers = gt_plane_layers(&sc).unwrap();
        let planes: Vec<Plane> = layers.iter().map(|l| Plane::from_layer(l, "x").unwrap()).collect();
        for s in &sc.settings {
            if let Some(o) = only { if !s.name.contains(o) { continue; } }
            let mut ts = TraceSettings::new(s.blur, s.focus, spp, 1);
            ts.footprint = tex;
            let t = Instant::now();
            let img = trace(&planes, &ts, Window::full(sc.bg.width, sc.bg.height), &|_| {}).unwrap();
            let el = t.elapsed().as_secs_f64();
            let b = s.coc_max.ceil() as usize;
            let sr = |i: &drbokeh::Image| { let mut o = i.clone(); o.map_inplace(|v| linear_to_srgb(v.clamp(0.0,1.0))); o };
            let mut ts2 = ts; ts2.seed = 2;
            let img2 = trace(&planes, &ts2, Window::full(sc.bg.width, sc.bg.height), &|_| {}).unwrap();
            println!("{name} {} planes {} spp {spp}: {el:.2}s  PSNR lin {:.2} sRGB {:.2}  rmse {:.5} selfnoise {:.5}  noborder PSNR {:.2}", s.name, planes.len(),
              psnr(&img, &s.gt, 1.0, b), psnr(&sr(&img), &sr(&s.gt), 1.0, b), rmse(&img,&s.gt,b), rmse(&img,&img2,b)/2f64.sqrt(), psnr(&img, &s.gt, 1.0, 0));
            drbokeh::io::write_exr(std::path::Path::new(&format!("/tmp/probe/{name}_{}_{spp}.exr", s.name)), &img, &["R","G","B"]).unwrap();
            drbokeh::io::write_exr(std::path::Path::new(&format!("/tmp/probe/{name}_{}_{spp}_b.exr", s.name)), &img2, &["R","G","B"]).unwrap();
        }
    }
}
