//! `drbokeh inspect`: what a photo holds (size, colour, the depth map it embeds and its
//! parameters), as text or JSON, and the embedded depth map written out for other tools.

use anyhow::Context;
use clap::Args;
use drbokeh::Error;
use drbokeh::io::ReadLimits;
use drbokeh::io::inspect::{Inspection, inspect, write_extracted_depth};
use std::path::PathBuf;

#[derive(Args)]
pub(crate) struct InspectArgs {
    /// The photo (JPEG with Dynamic Depth or GDepth XMP, or any supported image).
    photo: PathBuf,
    /// Print a machine-readable report (JSON) to stdout.
    #[arg(long)]
    json: bool,
    /// Write the embedded depth map: .exr or .npy (metric depth as decoded) or .png (16-bit,
    /// depth / Far).
    #[arg(long, value_name = "OUT")]
    extract_depth: Option<PathBuf>,
}

pub(crate) fn run(args: InspectArgs) -> anyhow::Result<()> {
    let limits = ReadLimits::default();
    if let Some(out) = &args.extract_depth {
        drbokeh::io::InputFiles::new([&args.photo]).check_write(out, "--extract-depth")?;
        drbokeh::io::OutputFormat::from_path(out)?;
    }
    let (report, embedded) = inspect(&args.photo, &limits)?;
    if let Some(out) = &args.extract_depth {
        let e = embedded.as_ref().ok_or_else(|| {
            Error::input(&args.photo, "embeds no depth map (no Dynamic Depth or GDepth XMP); --extract-depth has nothing to write")
        })?;
        let what = write_extracted_depth(out, e)?;
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
            let x = &g.xmp;
            let where_ = if x.extended_segments > 0 {
                format!(
                    "XMP: standard packet, and an extended packet of {} bytes over {} APP1 segments",
                    x.extended_bytes, x.extended_segments
                )
            } else {
                "XMP, standard packet".to_owned()
            };
            let p = g.container.prefix();
            let row = |field: &str| format!("{p}:{field}");
            writeln!(o, "depth: {} ({where_})", g.container.name())?;
            writeln!(o, "  {:<19} {}", row("Format"), g.format.name())?;
            writeln!(o, "  {:<19} {}", row("Near"), g.near)?;
            writeln!(o, "  {:<19} {}", row("Far"), g.far)?;
            writeln!(o, "  {:<19} {}", row("Units"), g.units.as_deref().unwrap_or("(not given)"))?;
            writeln!(o, "  {:<19} {}", row("MeasureType"), g.measure_type.as_deref().unwrap_or("(not given: OpticalAxis)"))?;
            let image = format!("{}x{}, {}-bit grey, {} bytes", g.width, g.height, g.bit_depth, g.data_bytes);
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
    writeln!(o, "matte: none embedded")?;
    if let Some(m) = &r.original_image {
        writeln!(o, "original image: GImage:Data ({m})")?;
    }
    writeln!(o, "(looked for: {}; not read yet: {})", r.embedded_formats_read.join(", "), r.embedded_formats_not_read.join(", "))?;
    for w in &r.warnings {
        eprintln!("warning: {w}");
    }
    Ok(())
}
