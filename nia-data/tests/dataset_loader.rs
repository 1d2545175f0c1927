//! Training ray sampling, the visibility cache and the prefetching loader, on the numpy-written
//! ZJU fixture and on `synth` output read through the same reader.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use nia_data::body::BodyModel;
use nia_data::dataset::loader::{
    eval_requests, load_scene, train_requests, BandGrid, BodyVolumeGrid, LoaderConfig, LoaderError,
    SceneLoader, SceneRequest, SceneSource, SceneTarget, TargetKind,
};
use nia_data::dataset::protocol::{EvalSplit, FrameRange, Protocol, SubjectFrames, ViewSet};
use nia_data::dataset::sampling::{border_band, sample_rays, BoxPadding, RaySamplingConfig};
use nia_data::dataset::vis_cache::{self, VisibilityCache, VisibilityQuery};
use nia_data::dataset::{DatasetConfig, Subject};
use nia_data::fitting::SmplAlignment;
use nia_data::geometry::occupancy::OccupancyGrid;
use nia_data::geometry::occupancy_memo::remembered;
use nia_data::geometry::rays::mask_at_box;
use nia_data::geometry::sparse::{remembered_pyramid, NeighbourMaps, SitePyramid, VoxelGridSpec};
use nia_data::geometry::surface_memo::remembered_surface;
use nia_data::geometry::visibility::DEFAULT_DEPTH_TOL_M;
use nia_data::rng::Rng;
use nia_data::scene::vertices_in_smpl_frame;
use nia_data::synth::capture::CaptureFlaws;
use nia_data::synth::{generate, SynthSpec};

/// Stored synthetic vertices are float32 LBS of the written model.
const SYNTH_LBS_TOL_M: f32 = 1e-5;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/zju")
}

fn scratch(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nia-dataset-loader-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn fixture_subject() -> Subject {
    Subject::open(&fixtures().join("CoreView_377"), &DatasetConfig::zju()).unwrap()
}

fn fixture_model() -> BodyModel {
    BodyModel::load(&fixtures().join("smpl_tiny.npz")).unwrap()
}

#[test]
fn training_rays_follow_nhp_rules_and_are_deterministic() {
    let s = fixture_subject();
    let frame = 1;
    let view = s.load_view(frame, 0).unwrap();
    let vertices = s.load_vertices(frame).unwrap();
    let body_box = BoxPadding::nhp().body_box(&vertices).unwrap();
    // The tiny image is 32 pixels wide: a 3-pixel band keeps some interior pixels.
    let config = RaySamplingConfig {
        rays_per_image: 256,
        body_fraction: 0.5,
        border_px: 3,
        patch_px: 0,
    };
    let sample = |seed| {
        sample_rays(
            &view.camera,
            &view.image,
            &view.mask,
            &body_box,
            &config,
            &mut Rng::new(seed),
        )
        .unwrap()
    };
    let rays = sample(5);
    assert_eq!(rays.len(), 256);
    let (w, h) = (view.width() as usize, view.height() as usize);
    let in_box = mask_at_box(&view.camera, &body_box);
    let band = border_band(&view.mask, w, h, config.border_px);
    assert!(band.iter().any(|b| *b), "the fixture has a mask border");
    for (k, &p) in rays.rays.pixels.iter().enumerate() {
        let p = p as usize;
        assert!(in_box[p], "ray {k} misses the box");
        assert!(!band[p], "ray {k} in the border band");
        assert!(rays.rays.near[k] < rays.rays.far[k] && rays.rays.near[k] > 0.0);
        if k < 128 {
            assert!(
                view.mask[p] && rays.on_body[k],
                "the first half is on the body"
            );
        }
        // Colour and direction belong to the pixel.
        assert_eq!(
            rays.rgb[k],
            [
                view.image[p * 3],
                view.image[p * 3 + 1],
                view.image[p * 3 + 2]
            ]
        );
        let (x, y) = ((p % w) as f32, (p / w) as f32);
        let (uv, _) = view
            .camera
            .project(rays.rays.origins[k] + rays.rays.dirs[k])
            .unwrap();
        assert!((uv.x - x).abs() < 1e-3 && (uv.y - y).abs() < 1e-3);
    }
    // The second half also reaches the background inside the box.
    assert!(rays.on_body[128..].iter().any(|b| !b));
    let again = sample(5);
    assert_eq!(rays, again);
    let other = sample(6);
    assert_ne!(rays.rays.pixels, other.rays.pixels);
}

/// Rays in patches (`patch_px`, the SSIM loss's): whole `P x P` squares of pixels, patch
/// after patch, row-major, inside the body box, half of them centred on the person; the same
/// seed the same rays; a patch larger than the image refused by name.
#[test]
fn training_rays_in_patches_are_whole_squares_in_the_box() {
    let s = fixture_subject();
    let view = s.load_view(1, 0).unwrap();
    let vertices = s.load_vertices(1).unwrap();
    let body_box = BoxPadding::nhp().body_box(&vertices).unwrap();
    let (w, h) = (view.width() as usize, view.height() as usize);
    let config = RaySamplingConfig {
        rays_per_image: 64,
        body_fraction: 0.5,
        border_px: 3,
        patch_px: 4,
    };
    let sample = |config: &RaySamplingConfig, seed| {
        sample_rays(
            &view.camera,
            &view.image,
            &view.mask,
            &body_box,
            config,
            &mut Rng::new(seed),
        )
    };
    let rays = sample(&config, 3).unwrap();
    assert_eq!(rays.len(), 64);
    let in_box = mask_at_box(&view.camera, &body_box);
    for patch in rays.rays.pixels.chunks(16) {
        let (x0, y0) = (patch[0] as usize % w, patch[0] as usize / w);
        for (i, &p) in patch.iter().enumerate() {
            assert_eq!(
                (p as usize % w, p as usize / w),
                (x0 + i % 4, y0 + i / 4),
                "row-major square"
            );
            assert!(in_box[p as usize]);
        }
    }
    // The first two patches are centred on the person.
    for patch in 0..2 {
        let centre = rays.rays.pixels[patch * 16 + 2 * 4 + 2] as usize;
        let near = (0..16).any(|i| view.mask[rays.rays.pixels[patch * 16 + i] as usize]);
        assert!(
            near,
            "patch {patch} around pixel {centre} touches the person"
        );
    }
    assert_eq!(rays, sample(&config, 3).unwrap());
    let huge = RaySamplingConfig {
        patch_px: w.max(h) + 1,
        ..config
    };
    let err = sample(&huge, 3).unwrap_err();
    assert!(err.to_string().contains("patch_px"), "{err}");
}

#[test]
fn visibility_cache_hits_and_invalidates() {
    let dir = scratch("vis");
    let cache = VisibilityCache::new(&dir);
    let s = fixture_subject();
    let model = fixture_model();
    let vertices = s.load_vertices(0).unwrap();
    let camera = s.cameras[1];
    let base = VisibilityQuery {
        subject: &s.name,
        frame: 0,
        view: 1,
        camera: &camera,
        vertices: &vertices,
        faces: &model.faces,
        depth_tol_m: DEFAULT_DEPTH_TOL_M,
    };
    let direct = vis_cache::compute(&base).unwrap();
    assert_eq!(direct.len(), 30);
    let visible = direct.iter().filter(|v| **v == 1).count();
    assert!(
        visible > 5 && visible < 30,
        "a closed body is partly hidden: {visible}"
    );
    let get = |query: VisibilityQuery<'_>| cache.get_or_compute(&query).unwrap();
    assert_eq!(get(base), direct);
    assert_eq!(cache.stats(), (0, 1));
    assert_eq!(get(base), direct);
    assert_eq!(cache.stats(), (1, 1), "second lookup is a hit");
    assert!(cache.entry_path(&s.name, 0, 1).is_file());
    // Changed inputs miss: a moved vertex, another tolerance, another camera size.
    let mut moved = vertices.clone();
    moved[3].x += 1e-4;
    let moved = VisibilityQuery {
        vertices: &moved,
        ..base
    };
    get(moved);
    assert_eq!(cache.stats(), (1, 2));
    get(VisibilityQuery {
        depth_tol_m: 0.05,
        ..moved
    });
    assert_eq!(cache.stats(), (1, 3));
    let bigger = s.raw_cameras[1];
    let bigger = VisibilityQuery {
        camera: &bigger,
        depth_tol_m: 0.05,
        ..moved
    };
    get(bigger);
    assert_eq!(cache.stats(), (1, 4));
    // A corrupt file is recomputed, not trusted.
    let path = cache.entry_path(&s.name, 0, 1);
    let mut bytes = std::fs::read(&path).unwrap();
    let n = bytes.len();
    bytes[n - 12] ^= 1;
    std::fs::write(&path, bytes).unwrap();
    let fresh = get(bigger);
    assert_eq!(cache.stats(), (1, 5));
    let recomputed = vis_cache::compute(&bigger).unwrap();
    assert_eq!(fresh, recomputed);
    let _ = std::fs::remove_dir_all(&dir);
}

fn fixture_protocol() -> Protocol {
    let mut p = Protocol::nhp();
    p.train = vec![SubjectFrames::new("CoreView_377", FrameRange::new(0, 2, 1))];
    p.train_num_input_views = 2;
    p.input_views = ViewSet::explicit(&[0, 2]);
    p.target_views = ViewSet::OthersThanInputs { stride: 1 };
    p.target_views_by_subject.clear();
    p.unseen_subjects = vec![SubjectFrames::new("CoreView_313", FrameRange::all_from(0))];
    p.seen_subjects_unseen_poses.clear();
    p.seen_subjects_seen_poses.clear();
    p.test_frame_stride = 1;
    p.validate().unwrap();
    p
}

fn fixture_source(cache: Option<VisibilityCache>) -> Arc<SceneSource> {
    let mut cfg313 = DatasetConfig::zju();
    cfg313.ratio = Some(1.0);
    let subjects = vec![
        fixture_subject(),
        Subject::open(&fixtures().join("CoreView_313"), &cfg313).unwrap(),
    ];
    Arc::new(SceneSource {
        subjects,
        faces: fixture_model().faces,
        cache,
        body_model: None,
    })
}

/// The whole-image requests of the protocol's unseen-subject split.
fn unseen_subject_requests(protocol: &Protocol, source: &SceneSource) -> Vec<SceneRequest> {
    let items = protocol
        .eval_items(EvalSplit::UnseenSubjects, |name| {
            let s = source.subjects.iter().find(|s| s.name == name).unwrap();
            (s.num_cameras(), s.num_frames())
        })
        .unwrap();
    eval_requests(&items, &source.subjects).unwrap()
}

fn small_loader_config(threads: usize) -> LoaderConfig {
    LoaderConfig {
        threads,
        prefetch: 3,
        sampling: RaySamplingConfig {
            rays_per_image: 64,
            border_px: 3,
            ..RaySamplingConfig::default()
        },
        ..LoaderConfig::default()
    }
}

#[test]
fn loader_yields_scenes_in_order_for_any_thread_count() {
    let source = fixture_source(None);
    let protocol = fixture_protocol();
    let mut requests = Vec::new();
    for epoch in 0..3 {
        requests.extend(train_requests(&protocol, &source.subjects, epoch, 11).unwrap());
    }
    assert_eq!(requests.len(), 6, "2 frames x 3 epochs");
    assert!(requests
        .iter()
        .all(|r| r.input_views.len() == 2 && r.target == TargetKind::Rays));
    assert_eq!(requests, {
        let mut again = Vec::new();
        for epoch in 0..3 {
            again.extend(train_requests(&protocol, &source.subjects, epoch, 11).unwrap());
        }
        again
    });
    requests.extend(unseen_subject_requests(&protocol, &source));
    assert_eq!(requests.len(), 6 + 2 * 2);

    let serial: Vec<_> = requests
        .iter()
        .enumerate()
        .map(|(i, r)| load_scene(&source, r, i, &small_loader_config(1)).unwrap())
        .collect();
    for threads in [1, 3] {
        let loader = SceneLoader::new(
            source.clone(),
            requests.clone(),
            small_loader_config(threads),
        )
        .unwrap();
        assert_eq!(loader.len(), requests.len());
        let scenes: Vec<_> = loader.map(|s| s.unwrap()).collect();
        assert_eq!(scenes, serial, "{threads} threads");
    }
    for (scene, request) in serial.iter().zip(&requests) {
        assert_eq!(scene.sources.len(), request.input_views.len());
        for src in &scene.sources {
            assert_eq!(src.visibility.len(), scene.vertices.len());
        }
        match (&scene.target, request.target) {
            (SceneTarget::Rays(r), TargetKind::Rays) => assert_eq!(r.len(), 64),
            (SceneTarget::Image { image, mask_at_box }, TargetKind::Image) => {
                assert_eq!(mask_at_box.len(), image.mask.len());
                assert!(mask_at_box.iter().any(|m| *m));
                assert_eq!(scene.subject, "CoreView_313");
            }
            _ => panic!("target kind differs from the request"),
        }
    }
}

/// SMPL jitter (`smpl_jitter_m`) moves the body of training scenes only: the same request
/// gives the same jittered body, another seed another; whole-image scenes keep the stored body;
/// the visibility stays the stored fit's; Th moves with the vertices.
#[test]
fn smpl_jitter_moves_training_bodies_only() {
    let source = fixture_source(None);
    let protocol = fixture_protocol();
    let mut requests = train_requests(&protocol, &source.subjects, 0, 11).unwrap();
    requests.extend(unseen_subject_requests(&protocol, &source));
    let jittered = LoaderConfig {
        smpl_jitter_m: 0.05,
        ..small_loader_config(1)
    };
    for (i, request) in requests.iter().enumerate() {
        let plain = load_scene(&source, request, i, &small_loader_config(1)).unwrap();
        let moved = load_scene(&source, request, i, &jittered).unwrap();
        assert_eq!(moved, load_scene(&source, request, i, &jittered).unwrap());
        for (a, b) in moved.sources.iter().zip(&plain.sources) {
            assert_eq!(a.visibility, b.visibility);
        }
        let shift: Vec<f32> = moved
            .vertices
            .iter()
            .zip(&plain.vertices)
            .map(|(a, b)| a.distance(*b))
            .collect();
        match request.target {
            TargetKind::Image => {
                assert_eq!(moved.vertices, plain.vertices);
                assert_eq!(moved.params, plain.params);
            }
            TargetKind::Rays => {
                let mean = shift.iter().sum::<f32>() / shift.len() as f32;
                assert!(mean > 0.0 && mean < 0.3, "mean shift {mean} m");
                assert!(moved.vertices.iter().all(|v| v.is_finite()));
                assert_ne!(moved.params.th, plain.params.th);
                let other = SceneRequest {
                    seed: request.seed + 1,
                    ..request.clone()
                };
                assert_ne!(
                    load_scene(&source, &other, i, &jittered).unwrap().vertices,
                    moved.vertices
                );
            }
        }
    }
}

#[test]
fn loader_reports_errors_in_place_and_stops_cleanly() {
    let source = fixture_source(None);
    let protocol = fixture_protocol();
    let mut requests = train_requests(&protocol, &source.subjects, 0, 1).unwrap();
    requests[1].frame = 99;
    let mut loader = SceneLoader::new(source, requests, small_loader_config(2)).unwrap();
    assert!(loader.next().unwrap().is_ok());
    let err = loader.next().unwrap().unwrap_err();
    assert!(err.to_string().contains("frame 99 out of range"), "{err}");
    assert!(loader.next().is_none());
    // Dropping a loader with scenes still in flight joins its workers.
    let source = fixture_source(None);
    let requests = train_requests(&fixture_protocol(), &source.subjects, 0, 2).unwrap();
    let mut loader = SceneLoader::new(source, requests, small_loader_config(2)).unwrap();
    loader.next();
    drop(loader);
}

/// Two synthetic people (one held out) in `frames` frames seen by `cameras` cameras of `size`
/// px, without supersampling.
fn two_people(frames: usize, cameras: usize, size: u32) -> SynthSpec {
    SynthSpec {
        frames,
        cameras,
        size,
        subjects: 2,
        supersample: 1,
        test_fraction: 0.5,
        ..SynthSpec::default()
    }
}

#[test]
fn synthetic_set_reads_through_the_same_reader() {
    let out = scratch("synth");
    let spec = two_people(3, 4, 48);
    let summary = generate(&spec, &out, &mut |_| {}).unwrap();
    let model = BodyModel::load(&summary.body_model).unwrap();
    let protocol = Protocol::synthetic(&spec, 1);
    protocol.validate().unwrap();
    let cfg = DatasetConfig {
        smpl_model: Some(summary.body_model.clone()),
        ..DatasetConfig::zju()
    };
    let mut subjects = Vec::new();
    for s in &summary.subjects {
        let subject = Subject::open(&s.dir, &cfg).unwrap();
        assert_eq!((subject.num_cameras(), subject.num_frames()), (4, 3));
        assert_eq!(subject.cameras[0].width, 24);
        for frame in 0..3 {
            let err = subject
                .lbs_max_error(&model, &summary.body_model, frame)
                .unwrap();
            assert!(
                err < SYNTH_LBS_TOL_M,
                "{}: frame {frame}: {err} m",
                subject.name
            );
        }
        let view = subject.load_view(0, 1).unwrap();
        assert!(view.mask_coverage() > 0.02, "{}", view.mask_coverage());
        protocol
            .check_subject(&subject.name, subject.num_cameras(), subject.num_frames())
            .unwrap();
        subjects.push(subject);
    }
    let report = nia_data::dataset::inspect(&summary.subjects[0].dir, &cfg).unwrap();
    assert!(report.lbs_max_err_m.unwrap() < SYNTH_LBS_TOL_M);
    let source = Arc::new(SceneSource {
        subjects,
        faces: model.faces.clone(),
        cache: Some(VisibilityCache::new(out.join("cache"))),
        body_model: None,
    });
    let requests = train_requests(&protocol, &source.subjects, 0, 3).unwrap();
    assert_eq!(requests.len(), 2, "1 train subject x 2 training frames");
    let loader = SceneLoader::new(source.clone(), requests, small_loader_config(2)).unwrap();
    for scene in loader {
        let scene = scene.unwrap();
        assert_eq!(scene.vertices.len(), model.num_vertices());
        assert!(scene.sources.iter().all(|s| s.visibility.contains(&1)));
    }
    let (hits, misses) = source.cache.as_ref().unwrap().stats();
    assert_eq!(
        (hits, misses),
        (0, 6),
        "2 scenes x 3 input views computed once"
    );
    let _ = std::fs::remove_dir_all(&out);
}

/// Loader throughput on a synthetic set at the paper's 512x512 (1024x1024 images halved).
/// Run: `cargo test -p nia-data --release --test dataset_loader -- --ignored --nocapture`.
#[test]
#[ignore]
fn bench_loader_scenes_per_second() {
    let out = scratch("bench");
    let spec = two_people(4, 8, 1024);
    let t = Instant::now();
    let summary = generate(&spec, &out, &mut |_| {}).unwrap();
    eprintln!("synth: {:.1} s", t.elapsed().as_secs_f64());
    let model = BodyModel::load(&summary.body_model).unwrap();
    let mut protocol = Protocol::synthetic(&spec, 1);
    protocol.train = summary
        .subjects
        .iter()
        .map(|s| {
            SubjectFrames::new(
                s.dir.file_name().unwrap().to_string_lossy(),
                FrameRange::all_from(0),
            )
        })
        .collect();
    protocol.unseen_subjects.clear();
    let subjects: Vec<Subject> = summary
        .subjects
        .iter()
        .map(|s| Subject::open(&s.dir, &DatasetConfig::zju()).unwrap())
        .collect();
    let cache = VisibilityCache::new(out.join("cache"));
    let source = Arc::new(SceneSource {
        subjects,
        faces: model.faces.clone(),
        cache: Some(cache),
        body_model: None,
    });
    let requests = |epoch| train_requests(&protocol, &source.subjects, epoch, 0).unwrap();
    for threads in [1, 2, 4] {
        for (label, epochs) in [("cold cache", 0..1u64), ("warm cache", 1..4u64)] {
            let list: Vec<_> = epochs.clone().flat_map(requests).collect();
            let n = list.len();
            let config = LoaderConfig {
                threads,
                prefetch: 2 * threads,
                ..LoaderConfig::default()
            };
            let t = Instant::now();
            for scene in SceneLoader::new(source.clone(), list, config).unwrap() {
                scene.unwrap();
            }
            let dt = t.elapsed().as_secs_f64();
            eprintln!(
                "threads {threads}, {label}: {n} scenes in {dt:.2} s = {:.2} scenes/s",
                n as f64 / dt
            );
        }
        let _ = std::fs::remove_dir_all(out.join("cache"));
    }
    let _ = std::fs::remove_dir_all(&out);
}

/// `band_grid`: the loader builds every training scene's band grid into the shared memo, where
/// the training step's sampler finds it (the same grid a fresh build gives); whole-image scenes
/// and a loader without `band_grid` build none.
#[test]
fn the_loader_builds_training_band_grids_ahead() {
    // Distances no other test uses: the memo holds nothing for them before this test.
    let (threshold, cell) = (0.0437, 0.0211);
    let source = fixture_source(None);
    let protocol = fixture_protocol();
    let mut requests = train_requests(&protocol, &source.subjects, 0, 11).unwrap();
    requests.extend(unseen_subject_requests(&protocol, &source));
    let off = LoaderConfig {
        smpl_jitter_m: 0.05,
        ..small_loader_config(1)
    };
    let on = LoaderConfig {
        band_grid: Some(BandGrid {
            threshold_m: threshold,
            cell_m: cell,
        }),
        ..off
    };
    for (i, request) in requests.iter().enumerate() {
        let scene = load_scene(&source, request, i, &off).unwrap();
        assert!(remembered(&scene.vertices, &source.faces, threshold, cell).is_none());
    }
    let mut built = 0;
    for (i, request) in requests.iter().enumerate() {
        let scene = load_scene(&source, request, i, &on).unwrap();
        let grid = remembered(&scene.vertices, &source.faces, threshold, cell);
        match request.target {
            TargetKind::Image => assert!(grid.is_none(), "scene {i}: a whole-image scene"),
            TargetKind::Rays => {
                let grid = grid.unwrap_or_else(|| panic!("scene {i}: no grid remembered"));
                let fresh =
                    OccupancyGrid::build(&scene.vertices, &source.faces, threshold, cell).unwrap();
                assert_eq!(*grid, fresh);
                built += 1;
            }
        }
    }
    assert!(built >= 2, "{built} training scenes");
}

/// `body_volume`: the loader builds every training scene's body-volume site pyramid into the
/// shared memo (the same pyramid a fresh build gives: every level's sites and every rulebook),
/// and its nearest-surface index whatever the setting; whole-image scenes get neither
/// pyramid. The vertices in the SMPL frame are the ones the scene's geometry computes.
#[test]
fn the_loader_builds_training_site_pyramids_and_surface_indices_ahead() {
    // A voxel size no other test uses: the memo holds no pyramid for it before this test.
    let volume = BodyVolumeGrid {
        grid: VoxelGridSpec {
            voxel_size_m: 0.0173,
            box_enlarge: 0.025,
        },
        levels: 4,
        neighbour_maps: true,
    };
    let source = fixture_source(None);
    let protocol = fixture_protocol();
    let mut requests = train_requests(&protocol, &source.subjects, 0, 13).unwrap();
    requests.extend(unseen_subject_requests(&protocol, &source));
    let config = LoaderConfig {
        smpl_jitter_m: 0.05,
        body_volume: Some(volume),
        ..small_loader_config(1)
    };
    let mut built = 0;
    for (i, request) in requests.iter().enumerate() {
        let scene = load_scene(&source, request, i, &config).unwrap();
        let smpl = vertices_in_smpl_frame(&scene.vertices, scene.params.rh, scene.params.th);
        let voxel_box = volume.grid.enclosing(&smpl).unwrap();
        let pyramid = remembered_pyramid(&smpl, &voxel_box, volume.levels);
        match request.target {
            TargetKind::Image => assert!(pyramid.is_none(), "scene {i}: a whole-image scene"),
            TargetKind::Rays => {
                let pyramid = pyramid.unwrap_or_else(|| panic!("scene {i}: no pyramid"));
                let fresh = SitePyramid::build(&smpl, &voxel_box, volume.levels).unwrap();
                assert_eq!(pyramid.levels.len(), volume.levels + 1);
                assert_eq!(pyramid.submanifold_rules, fresh.submanifold_rules);
                assert_eq!(pyramid.strided_rules, fresh.strided_rules);
                // ... with every rulebook's neighbour maps built (`neighbour_maps`).
                for (rules, fresh) in pyramid
                    .submanifold_rules
                    .iter()
                    .chain(&pyramid.strided_rules)
                    .zip(fresh.submanifold_rules.iter().chain(&fresh.strided_rules))
                {
                    assert!(fresh.built_neighbour_maps().is_none());
                    let built = rules
                        .built_neighbour_maps()
                        .unwrap_or_else(|| panic!("scene {i}: neighbour maps not built ahead"));
                    assert_eq!(*built, NeighbourMaps::new(fresh));
                }
                assert_eq!(pyramid.voxels.vertex_site, fresh.voxels.vertex_site);
                for (a, b) in pyramid.levels.iter().zip(&fresh.levels) {
                    assert_eq!(a.num_sites(), b.num_sites());
                    assert_eq!(a.origin_m, b.origin_m);
                }
                assert!(
                    remembered_surface(&scene.vertices, &source.faces).is_some(),
                    "scene {i}: no surface index"
                );
                built += 1;
            }
        }
    }
    assert!(built >= 2, "{built} training scenes");
}

/// SMPL alignment (`smpl_alignment`) in the loader: on a set whose stored fit is off the
/// people (the generator's fit error at level 2), every scene's body comes closer to the true
/// one (the same seed written without the error), training and evaluation alike; the params
/// move with the vertices; the metrics' region stays the stored fit's; the visibility is the
/// aligned body's, computed past the cache; without the setting nothing moves. The pose
/// refinement after it takes the bodies closer still, its params posing its vertices, and
/// without the body model it is refused by name.
#[test]
fn smpl_alignment_moves_the_fit_onto_the_people() {
    let out = scratch("alignment");
    let spec = |level: f32| SynthSpec {
        capture: CaptureFlaws {
            smpl_fit: level,
            ..CaptureFlaws::default()
        },
        seed: 5,
        ..two_people(2, 4, 96)
    };
    let fitted = generate(&spec(2.0), &out.join("fit"), &mut |_| {}).unwrap();
    let truth = generate(&spec(0.0), &out.join("truth"), &mut |_| {}).unwrap();
    let model = BodyModel::load(&fitted.body_model).unwrap();
    let cfg = DatasetConfig {
        smpl_model: Some(fitted.body_model.clone()),
        ..DatasetConfig::zju()
    };
    let open = |summary: &nia_data::synth::SynthSummary| -> Vec<Subject> {
        summary
            .subjects
            .iter()
            .map(|s| Subject::open(&s.dir, &cfg).unwrap())
            .collect()
    };
    let source = SceneSource {
        subjects: open(&fitted),
        faces: model.faces.clone(),
        cache: Some(VisibilityCache::new(out.join("cache"))),
        body_model: None,
    };
    let model = Arc::new(model);
    let with_model = SceneSource {
        subjects: open(&fitted),
        faces: model.faces.clone(),
        cache: None,
        body_model: Some(model.clone()),
    };
    let true_subjects = open(&truth);
    let plain = small_loader_config(1);
    let aligned = LoaderConfig {
        smpl_alignment: Some(SmplAlignment::default()),
        ..plain
    };
    let posed = LoaderConfig {
        smpl_alignment: Some(SmplAlignment {
            pose_iterations: 20,
            ..SmplAlignment::default()
        }),
        ..plain
    };
    // The pose refinement needs the body model.
    let request = SceneRequest {
        subject: 0,
        frame: 0,
        input_views: vec![0, 1, 3],
        target_view: 2,
        target: TargetKind::Image,
        seed: 9,
    };
    match load_scene(&source, &request, 0, &posed) {
        Err(e @ LoaderError::Alignment { .. }) => {
            assert!(e.to_string().contains("pose_iterations"), "{e}")
        }
        other => panic!("expected the missing body model to be named, got {other:?}"),
    }
    let without_model = Arc::new(SceneSource {
        subjects: open(&fitted),
        faces: model.faces.clone(),
        cache: None,
        body_model: None,
    });
    match SceneLoader::new(without_model, vec![request.clone()], posed) {
        Err(e @ LoaderError::AlignmentConfig(_)) => {
            assert!(e.to_string().contains("pose_iterations"), "{e}")
        }
        Err(e) => panic!("expected the missing body model to be named, got {e}"),
        Ok(_) => panic!("expected the missing body model to be named"),
    }
    let (mut before, mut after, mut after_pose) = (0.0f32, 0.0f32, 0.0f32);
    for (s, subject) in source.subjects.iter().enumerate() {
        for frame in 0..2 {
            let truth = true_subjects[s].load_vertices(frame).unwrap();
            for target in [TargetKind::Image, TargetKind::Rays] {
                let request = SceneRequest {
                    subject: s,
                    frame,
                    input_views: vec![0, 1, 3],
                    target_view: 2,
                    target,
                    seed: 9,
                };
                let stored = load_scene(&source, &request, 0, &plain).unwrap();
                let moved = load_scene(&source, &request, 0, &aligned).unwrap();
                assert_eq!(stored.alignment, None);
                let correction = moved.alignment.expect("the correction is reported");
                assert_eq!(correction.views_used, 3);
                assert!(correction.energy_after <= correction.energy_before);
                let mean = |v: &[glam::Vec3]| {
                    v.iter()
                        .zip(&truth)
                        .map(|(a, b)| a.distance(*b))
                        .sum::<f32>()
                        / v.len() as f32
                };
                before += mean(&stored.vertices);
                after += mean(&moved.vertices);
                // Rigid only for training scenes where `train_pose_iterations` is 0.
                let rendered_only = LoaderConfig {
                    smpl_alignment: posed.smpl_alignment.map(|a| SmplAlignment {
                        train_pose_iterations: Some(0),
                        ..a
                    }),
                    ..plain
                };
                let split = load_scene(&with_model, &request, 0, &rendered_only).unwrap();
                match target {
                    TargetKind::Rays => {
                        assert_eq!(split.pose_refinement, None);
                        assert_eq!(split.vertices, moved.vertices);
                    }
                    TargetKind::Image => assert!(split.pose_refinement.is_some()),
                }
                let refined = load_scene(&with_model, &request, 0, &posed).unwrap();
                after_pose += mean(&refined.vertices);
                let refinement = refined.pose_refinement.as_ref().expect("reported");
                assert!(refinement.energy_after <= refinement.energy_before);
                assert!(refinement.max_joint_deg <= 15.0 + 1e-3);
                // The refined params pose the refined vertices (the stored fit was posed by
                // the same model: no offsets).
                let again = model.lbs(&refined.params).vertices;
                for (a, b) in refined.vertices.iter().zip(&again) {
                    assert!(a.distance(*b) < 1e-4, "{}: frame {frame}", subject.name);
                }
                // The params still pose the same body: the SMPL frame did not move.
                let local =
                    vertices_in_smpl_frame(&stored.vertices, stored.params.rh, stored.params.th);
                let local_moved =
                    vertices_in_smpl_frame(&moved.vertices, moved.params.rh, moved.params.th);
                for (a, b) in local.iter().zip(&local_moved) {
                    let d = glam::Vec3::from_array(*a).distance(glam::Vec3::from_array(*b));
                    assert!(d < 1e-4, "{}: frame {frame}: {d} m", subject.name);
                }
                for (view, loaded) in moved.sources.iter().enumerate() {
                    let camera = &loaded.image.camera;
                    let expected = vis_cache::compute(&VisibilityQuery {
                        subject: &subject.name,
                        frame,
                        view: loaded.view,
                        camera,
                        vertices: &moved.vertices,
                        faces: &source.faces,
                        depth_tol_m: DEFAULT_DEPTH_TOL_M,
                    })
                    .unwrap();
                    assert_eq!(loaded.visibility, expected, "view {view}");
                }
                if let (
                    SceneTarget::Image { mask_at_box: a, .. },
                    SceneTarget::Image { mask_at_box: b, .. },
                ) = (&stored.target, &moved.target)
                {
                    assert_eq!(a, b, "the metrics' region is the stored fit's");
                }
            }
        }
    }
    // Level 2 is mostly joint error (4 degrees, 10 at the extremities), which no rigid motion
    // reaches: measured 0.43 -> 0.34 (the sum of the 8 scenes' means, metres).
    assert!(
        after < 0.9 * before,
        "mean vertex error over the scenes: stored {before}, aligned {after}"
    );
    // The pose refinement reaches the joints: measured 0.34 -> 0.23.
    assert!(
        after_pose < 0.8 * after,
        "mean vertex error over the scenes: aligned {after}, pose refined {after_pose}"
    );
    let _ = std::fs::remove_dir_all(&out);
}
