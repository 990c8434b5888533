//! Acceptance of depth from defocus on scenes it was never tuned on: README's "Evaluation:
//! `drbokeh bench --dfd`" claims, checked on a fresh generator seed at a small size.

use drbokeh::bench::dfd_eval::{self, DfdBenchOptions, DfdMethod, RowKind};
use drbokeh::bench::dfd_report::{ACCEPT_DB, Acceptance, acceptance, summary_table};

/// Generator seed of the scenes: used by no other test, README table or report (those use 0–3,
/// and the Mitsuba held-out sets 12, 13 and 21), and not chosen for its outcome: it was the
/// first of the fresh seeds tried (44, 45, 46; the commit message has all three).
const SEED: u64 = 44;
/// Generated scenes: README's claims are means over sets of 6 to 10 cases (with per-case
/// misses it reports itself), so the check is a mean over a set too, the size of its smallest.
const SCENES: usize = 6;

/// Protects README's acceptance claims for `drbokeh dfd` on unseen scenes, as far as they held
/// on fresh seeds: the default method (physical profile, loss Eqn. 7, automatic kernel) given
/// the all-in-focus photo and the thin-lens truth focused on the nearest plane
/// (1) re-renders the farthest-plane focus, in linear PSNR, on the mean of the cases, within
///     README's 2 dB ([`ACCEPT_DB`]) of what the true disparity re-renders, and
/// (2) has a lower mean disparity error than the no-occlusion ablation, over the frame and over
///     the textured pixels (README: "below"; no margin either way).
///
/// The bench's own code makes and scores the cases ([`dfd_eval::run`]: scenes of
/// `bench::scenes::generate`, traced by `bench::trace`) and its report's checks decide
/// ([`Acceptance`]). Two parts of README's claim are not checked here: they failed at README's
/// own configuration (64×64, 8 generated scenes) with this code, on the fresh seeds and on
/// README's seed 2 rerun (with its 2 Mitsuba scenes): a lower disparity error than the
/// Gaussian-PSF ablation (not on the mean over the frame on seeds 45 and 46, nor over textured
/// pixels on seeds 44, 45 and 2), and the sRGB re-render within 2 dB (a mean gap of 2.64 dB on
/// seed 44). At this test's size both held on seeds 44, 45 and 46, so passing here would say
/// little about them; `drbokeh bench --dfd` reports both. The Gaussian-PSF ablation is not run
/// (it was printed only: 25.5 -> 18.3 s alone on 2 cores).
#[test]
fn dfd_beats_no_occlusion_and_nears_the_true_rerender_on_unseen_scenes() {
    let tmp = tempfile::tempdir().unwrap();
    let opts = DfdBenchOptions {
        scenes: SCENES,
        width: 64,
        height: 48,
        seed: SEED,
        methods: vec![DfdMethod::Physical, DfdMethod::NoOcclusion],
        out: tmp.path().join("report"),
        ..DfdBenchOptions::default()
    };
    let res = dfd_eval::run(&opts, &mut |line| eprintln!("{line}")).unwrap();
    // All the numbers, shown with the failure (libtest prints a failing test's output).
    eprintln!("{}\n{}", summary_table(res.rows.iter()), acceptance(&res.rows));
    let checks = Acceptance::of(&res.rows).expect("rows of the default method");
    let [_, linear] = &checks.rerender;
    assert_eq!(linear.gaps.len(), SCENES, "cases with a default-method estimate");
    assert!(linear.holds(), "linear re-render: on the mean {:.2} dB below the true map's, more than {ACCEPT_DB} dB", linear.mean());
    let no_occlusion = checks.against(RowKind::Estimate(DfdMethod::NoOcclusion)).expect("the no-occlusion rows");
    assert!(
        no_occlusion.beats() && no_occlusion.beats_textured(),
        "disparity MAE not below the no-occlusion ablation's: {:.4} vs {:.4} overall, {:.4} vs {:.4} textured",
        no_occlusion.ours,
        no_occlusion.theirs,
        no_occlusion.ours_textured,
        no_occlusion.theirs_textured
    );
}
