//! `drbokeh inspect`: what a photo holds (size, colour, the depth map it embeds and its
//! parameters), as text or JSON, and the embedded depth map written out for other tools.

use anyhow::Context;
use clap::Args;
use drbokeh::Error;
use drbokeh::io::ReadLimits;
use drbokeh::io::inspect::{Inspection, inspect, write_extracted_depth, write_extracted_matte};
use std::path::PathBuf;

#[derive(Args)]
pub(crate) struct InspectArgs {
    /// The photo (JPEG with Dynamic Depth or GDepth XMP, HEIC with a depth image and portrait
    /// matte, or any supported image).
    photo: PathBuf,
    /// Print a machine-readable report (JSON) to stdout.
    #[arg(long)]
    json: bool,
    /// Write the embedded depth map: .exr or .npy (metric depth as decoded) or .png (16-bit,
    /// depth / Far).
    #[arg(long, value_name = "OUT")]
    extract_depth: Option<PathBuf>,
    /// Write the embedded matte (a HEIC portrait matte): .png (grey as stored), .exr (channel A)
    /// or .npy, values in [0, 1] at the matte's own size.
    #[arg(long, value_name = "OUT")]
    extract_matte: Option<PathBuf>,
}

pub(crate) fn run(args: InspectArgs) -> anyhow::Result<()> {
    let limits = ReadLimits::default();
    let outs = [(&args.extract_depth, "--extract-depth"), (&args.extract_matte, "--extract-matte")];
    for (out, flag) in outs {
        if let Some(out) = out {
            drbokeh::io::InputFiles::new([&args.photo]).check_write(out, flag)?;
            drbokeh::io::OutputFormat::from_path(out)?;
        }
    }
    if let (Some(a), Some(b)) = (&args.extract_depth, &args.extract_matte) {
        drbokeh::io::check_distinct(&[(a.as_path(), "--extract-depth"), (b.as_path(), "--extract-matte")])?;
    }
    let (report, embedded) = inspect(&args.photo, &limits)?;
    if let Some(out) = &args.extract_depth {
        let e = embedded.depth.as_ref().ok_or_else(|| {
            Error::input(
                &args.photo,
                "embeds no depth map (no Dynamic Depth, GDepth XMP or HEIF depth image); --extract-depth has nothing to write",
            )
        })?;
        let what = write_extracted_depth(out, e)?;
        eprintln!("wrote {} ({what})", out.display());
    }
    if let Some(out) = &args.extract_matte {
        let m = embedded
            .matte
            .as_ref()
            .ok_or_else(|| Error::input(&args.photo, "embeds no matte (no HEIF portrait matte); --extract-matte has nothing to write"))?;
        let what = write_extracted_matte(out, m)?;
        eprintln!("wrote {} ({what})", out.display());
    }
    if args.json {
        crate::print_json(&report)?;
    } else {
        // A reader that went away (`drbokeh inspect PHOTO | head`) is not an error.
        match print_text(&report) {
            Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => return Err(e).context("cannot write to standard output"),
            _ => {}
        }
    }
    Ok(())
}

fn print_text(r: &Inspection) -> std::io::Result<()> {
    use std::io::Write;
    let mut o = std::io::stdout().lock();
    writeln!(o, "{}: {}, {}x{}, {}, {}-bit", r.path, r.format, r.width, r.height, r.colour, r.bit_depth)?;
    match &r.depth {
        Some(d) => {
            let g = &d.info;
            let where_ = match &g.xmp {
                Some(x) if x.extended_segments > 0 => format!(
                    "XMP: standard packet, and an extended packet of {} bytes over {} APP1 segments",
                    x.extended_bytes, x.extended_segments
                ),
                Some(_) => "XMP, standard packet".to_owned(),
                None => "auxiliary image".to_owned(),
            };
            if let Some(h) = &g.heif {
                writeln!(o, "depth: {} (item {})", g.container.name(), h.item_id)?;
                writeln!(o, "  {:<19} {}", "representation", h.representation.unwrap_or("(not stated: read as relative disparity)"))?;
                for (name, v) in [("z_near", h.z_near), ("z_far", h.z_far), ("d_min", h.d_min), ("d_max", h.d_max)] {
                    if let Some(v) = v {
                        writeln!(o, "  {name:<19} {v}")?;
                    }
                }
                writeln!(o, "  {:<19} {}x{}, {}-bit grey", "image", g.width, g.height, g.bit_depth)?;
                writeln!(o, "  {:<19} {} .. {} (near {}, far {})", "depth range", d.depth_min, d.depth_max, g.near, g.far)?;
                return print_tail(&mut o, r);
            }
            let p = g.container.prefix();
            let row = |field: &str| format!("{p}:{field}");
            writeln!(o, "depth: {} ({where_})", g.container.name())?;
            writeln!(o, "  {:<19} {}", row("Format"), g.format.name())?;
            writeln!(o, "  {:<19} {}", row("Near"), g.near)?;
            writeln!(o, "  {:<19} {}", row("Far"), g.far)?;
            writeln!(o, "  {:<19} {}", row("Units"), g.units.as_deref().unwrap_or("(not given)"))?;
            writeln!(o, "  {:<19} {}", row("MeasureType"), g.measure_type.as_deref().unwrap_or("(not given: OpticalAxis)"))?;
            let bytes = g.data_bytes.map(|b| format!(", {b} bytes")).unwrap_or_default();
            let image = format!("{}x{}, {}-bit grey{bytes}", g.width, g.height, g.bit_depth);
            match &g.item {
                None => {
                    writeln!(o, "  {:<19} {}", row("Mime"), g.mime)?;
                    writeln!(o, "  {:<19} {image}", row("Data"))?;
                }
                Some(i) => {
                    writeln!(o, "  {:<19} {} (camera {})", row("DepthURI"), i.uri, i.camera)?;
                    writeln!(
                        o,
                        "  {:<19} {}, {image}, at byte {} (Item:Length {}, Item:Padding {})",
                        format!("Container:Item {}", i.index),
                        g.mime,
                        i.offset,
                        i.length,
                        i.padding
                    )?;
                    if let Some(c) = &i.confidence_uri {
                        writeln!(o, "  {:<19} {c} (not used)", row("ConfidenceURI"))?;
                    }
                }
            }
            writeln!(o, "  {:<19} {} .. {}", "depth range", d.depth_min, d.depth_max)?;
            if let Some(c) = &g.confidence_mime {
                writeln!(o, "  {:<19} {c} (not used)", row("Confidence"))?;
            }
        }
        None => writeln!(o, "depth: none embedded")?,
    }
    print_tail(&mut o, r)
}

/// The matte, the other auxiliary images, what was looked for, and the warnings.
fn print_tail(o: &mut impl std::io::Write, r: &Inspection) -> std::io::Result<()> {
    match &r.matte {
        Some(m) => writeln!(o, "matte: {}", m.describe())?,
        None => writeln!(o, "matte: none embedded")?,
    }
    for a in r.auxiliary.iter().filter(|a| a.used_as != "matte") {
        writeln!(o, "auxiliary image {}: {} {}x{} ({})", a.item_id, a.aux_type, a.width, a.height, a.used_as)?;
    }
    if let Some(m) = &r.original_image {
        writeln!(o, "original image: GImage:Data ({m})")?;
    }
    writeln!(o, "(looked for: {}; not read yet: {})", r.embedded_formats_read.join(", "), r.embedded_formats_not_read.join(", "))?;
    for w in &r.warnings {
        eprintln!("warning: {w}");
    }
    Ok(())
}
