use drbokeh::bench::run::*;
use drbokeh::bench::scenes::generate;
use drbokeh::bench::trace::*;
use drbokeh::color::Transfer;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let idx: usize = a[1].parse().unwrap();
    let sc = generate(1, idx, 256, 256, &[]);
    println!("{} planes {:?} blur {} focus {} maxcoc {} thin {} hl {}", sc.name, sc.planes.iter().map(|p| (p.name.clone(), p.disparity)).collect::<Vec<_>>(), sc.blur, sc.focus, sc.max_coc, sc.thin, sc.highlights);
    let inp = sc.inputs().unwrap();
    let ts = TraceSettings::new(sc.blur, sc.focus, 256, 1);
    let gt = trace(&sc.trace_planes(), &ts, sc.window(), &|_| {}).unwrap();
    let case = Case { scene: sc.name.clone(), setting: "x".into(), categories: vec![], blur: sc.blur, focus: sc.focus, max_coc: sc.max_coc, border: sc.max_coc.ceil() as usize, gt: gt.clone(), gt_noise: None, inputs: inp.clone() };
    let p = |n: &str, i: &drbokeh::Image| drbokeh::io::write_png(std::path::Path::new(&format!("/tmp/probe/{n}.png")), i, 8, Transfer::Srgb).unwrap();
    p("gt", &gt); p("aif", &inp.aif);
    p("matte", &inp.matte);
    for m in [Method::Layers, Method::Scatter] {
        let img = render_method(&case, m, Variant::Fast(2)).unwrap();
        let s = score(&img, &gt, case.border);
        println!("{:?} psnr srgb {:.2} lin {:.2}", m, s.psnr_srgb, s.psnr);
        p(m.short(), &img);
    }
}
