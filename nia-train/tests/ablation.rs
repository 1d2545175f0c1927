//! `nia-train ablation` end to end on a tiny dataset (2 steps per variant): every row of the
//! paper's Table 3 is trained and evaluated, the table, JSON and picture are written, a rerun
//! resumes instead of retraining; and the orderings' verdicts on hand-made rows.

use nia_model::variant::Variant;
use nia_train::ablation::{orderings, AblationRow};

mod common;

fn row(variant: Variant, views: usize, psnr: f64) -> AblationRow {
    AblationRow {
        label: format!("{} {views}", variant.name()),
        variant,
        views,
        task: "novel_view",
        images: 1,
        psnr,
        ssim: 0.5,
        psnr_no_skip: None,
        ssim_no_skip: None,
        train_seconds: 1.0,
        seconds_per_image: 1.0,
        c0_share_seen: None,
    }
}

#[test]
fn orderings_name_each_verdict_and_gap() {
    let rows = vec![
        row(Variant::NoBody, 3, 20.0),
        row(Variant::NoIbr, 3, 21.0),
        row(Variant::SimpleAverage, 3, 23.0),
        row(Variant::CosineWeighted, 3, 22.5),
        row(Variant::Full, 3, 23.5),
        row(Variant::Full, 2, 22.0),
        row(Variant::Full, 1, 19.0),
    ];
    let lines = orderings(&rows);
    assert_eq!(
        lines,
        vec![
            "e > d > c: does not hold (+1.00 dB, -0.50 dB)".to_string(),
            "e > a: holds (+3.50 dB)".to_string(),
            "e > b: holds (+2.50 dB)".to_string(),
            "1 < 2 < 3 views: holds (+3.00 dB, +1.50 dB)".to_string(),
        ]
    );
    // A missing variant is "not measured", never a verdict.
    let partial = orderings(&rows[4..5]);
    assert_eq!(partial[1], "e > a: not measured");
}

#[test]
fn ablation_command_trains_evaluates_and_resumes() {
    let dir = common::scratch("ablation", "run");
    let config = common::tiny_config(&dir, 2, 5, "validate_every = 0");
    let out = dir.join("ablation");
    let run = || {
        common::nia_train()
            .arg("ablation")
            .arg("--config")
            .arg(&config)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap()
    };
    let first = run();
    let stdout = String::from_utf8_lossy(&first.stdout);
    assert!(
        first.status.success(),
        "ablation failed: {}\n{stdout}",
        String::from_utf8_lossy(&first.stderr)
    );
    // Plain lines (no terminal here): a row per variant, the orderings, the files.
    for line in [
        "(a) no_body",
        "(b) no_ibr",
        "(c) simple_average",
        "(d) cosine_weighted",
        "(e) full, 1 view",
        "e > a: ",
    ] {
        assert!(stdout.contains(line), "{line} missing from:\n{stdout}");
    }
    let rows: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("ablation.json")).unwrap()).unwrap();
    let rows = rows.as_array().unwrap();
    // 5 variants, (e) with 2 and 1 views, and (e) in novel pose when the split has a second
    // frame of the held-out subject.
    assert!(rows.len() >= 7, "{} rows", rows.len());
    for r in rows {
        let psnr = r["psnr"].as_f64().unwrap();
        let ssim = r["ssim"].as_f64().unwrap();
        assert!(psnr.is_finite() && psnr > 0.0, "{r}");
        assert!(ssim.is_finite() && ssim <= 1.0, "{r}");
    }
    assert_eq!(rows[0]["variant"], "no_body");
    assert!(rows[0]["psnr_no_skip"].as_f64().is_some());
    let table = std::fs::read_to_string(out.join("ablation.md")).unwrap();
    assert!(table.contains("| (e) full |") && table.contains("e > d > c: "));
    let picture = image::open(out.join("ablation.png")).unwrap();
    assert!(picture.width() > picture.height(), "a row of tiles");
    for variant in Variant::ALL {
        assert!(
            out.join(variant.name()).join("train_seconds.txt").is_file(),
            "{}",
            variant.name()
        );
    }

    // A rerun resumes every variant from its last checkpoint: no step is trained again, and
    // the scores are the same.
    let second = run();
    assert!(second.status.success());
    let again: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("ablation.json")).unwrap()).unwrap();
    for (a, b) in rows.iter().zip(again.as_array().unwrap()) {
        assert_eq!(a["psnr"], b["psnr"], "{}", a["label"]);
    }
    let _ = std::fs::remove_dir_all(&dir);
}
