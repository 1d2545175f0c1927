//! How far the SMPL alignment moves the fits of a synthetic set's unseen-subject test scenes
//! towards the bodies their images show.
//!
//! ```text
//! cargo run --all-features -p nia-data --example alignment_error -- FLAWED_SET TRUE_SET ['SETTINGS']
//! ```
//!
//! `FLAWED_SET`: a synthetic set written with the fit error (`smpl-fit`); `TRUE_SET`: the same
//! generator seed written without it (`--capture none`, or the same flaws without `smpl-fit`),
//! whose `vertices/` are the true bodies. `SETTINGS`: `[data] smpl_alignment` as JSON (default
//! `{}`, the rigid alignment; `{"pose_iterations": 20}` adds the pose refinement). Each scene is
//! loaded exactly as `nia-infer eval --split test` loads it (its source views, the loader's
//! alignment); prints, per (subject, frame), the mean distance of the fit's vertices from the
//! true ones as stored, as aligned and as moved by the best pure translation (the "oracle", the
//! mean offset, which no method has), then the means over the scenes (centimetres) and the
//! loader's time per aligned scene (images and visibility included).

use std::collections::BTreeSet;
use std::error::Error;
use std::path::PathBuf;
use std::time::Instant;

use glam::Vec3;
use nia_data::dataset::loader::{load_scene, LoaderConfig, SceneRequest, TargetKind};
use nia_data::dataset::protocol::EvalSplit;
use nia_data::dataset::{DataConfig, DatasetConfig, DatasetFormat, OpenedDataset, Subject};
use nia_data::fitting::SmplAlignment;

fn mean_cm(a: &[Vec3], b: &[Vec3]) -> f64 {
    let sum: f64 = a
        .iter()
        .zip(b)
        .map(|(p, q)| f64::from(p.distance(*q)))
        .sum();
    100.0 * sum / a.len() as f64
}

fn main() -> Result<(), Box<dyn Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if !(2..=3).contains(&args.len()) {
        return Err("usage: alignment_error FLAWED_SET TRUE_SET ['SETTINGS (JSON)']".into());
    }
    let (flawed, truth) = (PathBuf::from(&args[0]), PathBuf::from(&args[1]));
    let settings: SmplAlignment = serde_json::from_str(args.get(2).map_or("{}", String::as_str))
        .map_err(|e| format!("SETTINGS: expected `[data] smpl_alignment` as a JSON object: {e}"))?;
    settings.validate()?;

    // Synthetic sets are read at the size they were written, as the shipped configs read them.
    let data = DataConfig {
        ratio: Some(1.0),
        ..DataConfig::at(&flawed)
    };
    let spec = data.own_synth_spec()?;
    let protocol = data.protocol(spec.as_ref())?;
    let split = EvalSplit::UnseenSubjects;
    let opened = OpenedDataset::open_split(&data, protocol, split)?;
    let subjects = &opened.source.subjects;
    let items = opened.protocol.eval_items(split, |name| {
        subjects
            .iter()
            .find(|s| s.name == name)
            .map_or((0, 0), |s| (s.num_cameras(), s.num_frames()))
    })?;
    let scenes: BTreeSet<(String, usize, Vec<usize>)> = items
        .into_iter()
        .map(|item| (item.subject, item.frame, item.input_views))
        .collect();
    let true_reader = DatasetConfig {
        ratio: Some(1.0),
        smpl_model: Some(truth.join("body_model.npz")),
        ..DatasetConfig::for_format(DatasetFormat::Zju)
    };
    let plain = LoaderConfig::default();
    let aligned = LoaderConfig {
        smpl_alignment: Some(settings),
        ..LoaderConfig::default()
    };

    let (mut stored_sum, mut aligned_sum, mut oracle_sum, mut seconds) = (0.0, 0.0, 0.0, 0.0);
    println!("subject frame stored_cm aligned_cm oracle_cm joints_mean_deg joints_max_deg");
    for (subject, frame, input_views) in &scenes {
        let index = opened
            .subject_index(subject)
            .ok_or_else(|| format!("{subject}: not opened"))?;
        let request = SceneRequest {
            subject: index,
            frame: *frame,
            input_views: input_views.clone(),
            target_view: input_views[0],
            target: TargetKind::Image,
            seed: 0,
        };
        let true_body = Subject::open(&truth.join(subject), &true_reader)?.load_vertices(*frame)?;
        let stored = load_scene(&opened.source, &request, 0, &plain)?;
        let start = Instant::now();
        let moved = load_scene(&opened.source, &request, 0, &aligned)?;
        seconds += start.elapsed().as_secs_f64();
        let (e0, e1) = (
            mean_cm(&stored.vertices, &true_body),
            mean_cm(&moved.vertices, &true_body),
        );
        let offset = true_body
            .iter()
            .zip(&stored.vertices)
            .map(|(t, v)| *t - *v)
            .sum::<Vec3>()
            / true_body.len().max(1) as f32;
        let shifted: Vec<Vec3> = stored.vertices.iter().map(|&v| v + offset).collect();
        let oracle = mean_cm(&shifted, &true_body);
        let (mean_deg, max_deg) = moved
            .pose_refinement
            .as_ref()
            .map_or((0.0, 0.0), |r| (r.mean_joint_deg, r.max_joint_deg));
        println!("{subject} {frame} {e0:.3} {e1:.3} {oracle:.3} {mean_deg:.2} {max_deg:.2}");
        stored_sum += e0;
        aligned_sum += e1;
        oracle_sum += oracle;
    }
    let n = scenes.len().max(1) as f64;
    println!(
        "mean over {} scenes: stored {:.3} cm, aligned {:.3} cm, oracle {:.3} cm; {:.0} ms per aligned scene",
        scenes.len(),
        stored_sum / n,
        aligned_sum / n,
        oracle_sum / n,
        1000.0 * seconds / n
    );
    Ok(())
}
