//! Loading a `.nia` model file for inference: the network on the chosen backend, with the run
//! config it was trained with (whose data, protocol and sampling settings are the defaults of
//! every command).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context;
use burn::prelude::Device;
use clap::Args;
use nia_data::dataset::protocol::{EvalItem, EvalSplit};
use nia_data::dataset::{DataConfig, OpenedDataset, ProtocolName};
use nia_eval::eval::{evaluate_images, EvalError, EvalOptions, EvaluatedImage, ImageResult};
use nia_eval::perceptual::LpipsFiles;
use nia_eval::run_settings::RunSettings;
use nia_model::device::{Backend, DeviceSpec};
use nia_model::lpips::{Lpips, LpipsNet};
use nia_model::render_options::{RenderOptions, DEFAULT_OCCUPANCY_CELL_M};
use nia_model::renderer::call_size::rays_per_chunk;
use nia_model::sampler::{RaySampler, DEFAULT_BAND_MARGIN_M};
use nia_model::store::model_file::ModelFile;
use nia_model::NiaModel;

/// The model and how to run it (shared by render, animate and eval).
#[derive(Args, Debug, Clone)]
pub struct ModelArgs {
    /// Model file written by `nia-infer export`.
    #[arg(long)]
    pub model: PathBuf,
    /// Backend: ndarray, flex or wgpu (default: flex on the CPU, also for a model trained on a
    /// GPU; the command says so).
    #[arg(long, value_parser = str::parse::<Backend>)]
    pub backend: Option<Backend>,
    /// Which GPU of a GPU backend (`--backend wgpu --device 1`: the second discrete GPU).
    #[arg(long)]
    pub device: Option<usize>,
    /// Samples per ray (default: the training setting stored in the model file).
    #[arg(long)]
    pub samples: Option<usize>,
    /// Rays rendered together (sampled, walked front to back, composited); the network sees
    /// their points in calls of at most 65,536 whatever the chunk. Default: on the CPU as many
    /// as keep a depth segment within 16,384 points (4096 rays of 32 samples with early
    /// termination, 16,384 of 8, 1024 without); on a GPU 2^22 samples (65,536 rays of 64 samples):
    /// fewer, fuller calls.
    #[arg(long)]
    pub chunk: Option<usize>,
    /// Empty-space skipping: on or off (default: the model's `[render]` setting, on).
    #[arg(long, value_parser = parse_switch)]
    pub skip_empty_space: Option<bool>,
    /// Distance from the SMPL surface within which samples are evaluated, metres (default:
    /// the model's `[render]` setting).
    #[arg(long)]
    pub empty_space_m: Option<f32>,
    /// Early ray termination: a ray stops evaluating samples once its transmittance is below
    /// this; 0 turns it off (default: the model's `[render]` setting, 1e-3).
    #[arg(long)]
    pub early_termination: Option<f32>,
    /// Colour culling: per ray, samples whose weights sum to at most this get no colour
    /// evaluation; 0 turns it off (default: the model's `[render]` setting, 1e-3).
    #[arg(long)]
    pub colour_culling: Option<f32>,
    /// Colour once per ray: the colour at the N samples of each ray with the largest weights,
    /// composited with the ray's opacity (0: every sample, the paper's; default: the model's
    /// `[render]` setting, 0).
    #[arg(long)]
    pub colour_points: Option<usize>,
    /// The density baked once per pose on a grid of this node spacing (metres), read at every
    /// view's samples (0: F_sigma at every sample, the paper's; default: the model's
    /// `[render]` setting, 0).
    #[arg(long)]
    pub density_grid_m: Option<f32>,
    /// Visual-hull carving with the source views' person masks: on or off (default: the
    /// model's `[render]` setting; off where it has none).
    #[arg(long, value_parser = parse_switch)]
    pub visual_hull: Option<bool>,
    /// The fitted body's silhouette, shrunk by N pixels, counts as person in every source mask
    /// before carving; `off` uses the masks as they are (default: the model's `[render]`
    /// setting, off).
    #[arg(long, value_parser = parse_off_or_pixels)]
    pub hull_body_erode_px: Option<OffOrPixels>,
    /// Rays per pixel side: every pixel the mean of N x N rays over its square, N x N times
    /// the work of 1 (one ray through the centre, the paper's) (default: the model's
    /// `[render]` setting).
    #[arg(long)]
    pub supersample: Option<usize>,
    /// c0's odds in the learned blend multiplied by S at rendering: below 1 the blend leans on
    /// the source colours (default: the model's `[render]` setting; 1, the paper's blend).
    #[arg(long)]
    pub c0_weight_scale: Option<f32>,
    /// Ray sampling: band (around the posed SMPL surface) or stratified (the whole box, the
    /// paper's) (default: the model's training setting).
    #[arg(long, value_parser = parse_sampler_kind)]
    pub ray_sampler: Option<SamplerKind>,
    /// Reach of the band sampler beyond the posed SMPL surface, metres (default: the model's
    /// training setting, 0.05); wider tolerates an SMPL fit that is off the body.
    #[arg(long)]
    pub band_margin_m: Option<f32>,
}

/// The kinds of `--ray-sampler`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SamplerKind {
    /// Samples around the posed SMPL surface.
    Band,
    /// Samples over the whole box.
    Stratified,
}

/// `off` (`None`) or a pixel count: the value of `--hull-body-erode-px`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OffOrPixels(pub Option<usize>);

fn parse_off_or_pixels(s: &str) -> Result<OffOrPixels, String> {
    match s {
        "off" => Ok(OffOrPixels(None)),
        n => n
            .parse()
            .map(|px| OffOrPixels(Some(px)))
            .map_err(|_| format!("`{n}`: expected off or a number of pixels")),
    }
}

fn parse_sampler_kind(s: &str) -> Result<SamplerKind, String> {
    match s {
        "band" => Ok(SamplerKind::Band),
        "stratified" => Ok(SamplerKind::Stratified),
        other => Err(format!("`{other}`: expected band or stratified")),
    }
}

impl ModelArgs {
    /// `base` (the `[render]` options of the model file `source`) with this command line's
    /// overrides, checked ([`RenderOptions::check`]): a value out of bounds is an error naming
    /// its flag, or the model file's key where no flag set it.
    pub fn render_options(
        &self,
        base: RenderOptions,
        source: &Path,
    ) -> anyhow::Result<RenderOptions> {
        let mut options = base;
        let overrides = [
            ("skip_empty_space", self.skip_empty_space.is_some()),
            ("empty_space_m", self.empty_space_m.is_some()),
            ("early_termination", self.early_termination.is_some()),
            ("colour_culling", self.colour_culling.is_some()),
            ("colour_points", self.colour_points.is_some()),
            ("density_grid_m", self.density_grid_m.is_some()),
            ("visual_hull", self.visual_hull.is_some()),
            ("hull_body_erode_px", self.hull_body_erode_px.is_some()),
            ("supersample", self.supersample.is_some()),
            ("c0_weight_scale", self.c0_weight_scale.is_some()),
        ];
        if let Some(on) = self.skip_empty_space {
            options.skip_empty_space = on;
        }
        if let Some(m) = self.empty_space_m {
            options.empty_space_m = m;
        }
        if let Some(e) = self.early_termination {
            options.early_termination = e;
        }
        if let Some(e) = self.colour_culling {
            options.colour_culling = e;
        }
        if let Some(k) = self.colour_points {
            options.colour_points = k;
        }
        if let Some(m) = self.density_grid_m {
            options.density_grid_m = m;
        }
        if let Some(on) = self.visual_hull {
            options.visual_hull = on;
        }
        if let Some(OffOrPixels(px)) = self.hull_body_erode_px {
            options.hull_body_erode_px = px;
        }
        if let Some(s) = self.supersample {
            options.supersample = s;
        }
        if let Some(s) = self.c0_weight_scale {
            options.c0_weight_scale = s;
        }
        if let Err(e) = options.check() {
            let from_flag = overrides.iter().any(|&(key, set)| set && key == e.key);
            if from_flag {
                anyhow::bail!(
                    "--{} {}: expected {}",
                    e.key.replace('_', "-"),
                    e.got,
                    e.expected
                );
            }
            anyhow::bail!("{}: `[render] {e}`", source.display());
        }
        Ok(options)
    }

    /// `trained` (the model's ray sampler) with `--ray-sampler` and `--band-margin-m`, checked:
    /// a margin for a stratified sampler, or out of bounds, is an error naming the flag.
    pub fn ray_sampler(&self, trained: RaySampler) -> anyhow::Result<RaySampler> {
        let (trained_margin, cell_m) = match trained {
            RaySampler::Band { margin_m, cell_m } => (margin_m, cell_m),
            RaySampler::Stratified => (DEFAULT_BAND_MARGIN_M, DEFAULT_OCCUPANCY_CELL_M),
        };
        let kind = self.ray_sampler.unwrap_or(match trained {
            RaySampler::Band { .. } => SamplerKind::Band,
            RaySampler::Stratified => SamplerKind::Stratified,
        });
        let sampler = match kind {
            SamplerKind::Stratified => {
                if let Some(m) = self.band_margin_m {
                    anyhow::bail!(
                        "--band-margin-m {m}: the ray sampler is stratified; pass --ray-sampler band"
                    );
                }
                RaySampler::Stratified
            }
            SamplerKind::Band => RaySampler::Band {
                margin_m: self.band_margin_m.unwrap_or(trained_margin),
                cell_m,
            },
        };
        if let Err(e) = sampler.check() {
            anyhow::bail!("--band-margin-m: {e}");
        }
        Ok(sampler)
    }
}

pub fn parse_switch(s: &str) -> Result<bool, String> {
    match s.to_ascii_lowercase().as_str() {
        "on" | "true" | "yes" | "1" => Ok(true),
        "off" | "false" | "no" | "0" => Ok(false),
        other => Err(format!("`{other}`: expected on or off")),
    }
}

/// A loaded model file.
pub struct LoadedModel {
    pub path: PathBuf,
    pub model: NiaModel,
    /// The settings of the run the model was trained with.
    pub run: RunSettings,
    /// Training steps taken.
    pub step: u64,
    /// The backend it runs on.
    pub backend: Backend,
    pub device: Device,
}

impl LoadedModel {
    /// Reads, checks and loads `args.model` on `args.backend`.
    pub fn open(args: &ModelArgs) -> anyhow::Result<Self> {
        if args.chunk == Some(0) {
            anyhow::bail!("--chunk must be at least 1");
        }
        if args.samples.is_some_and(|s| s < 2) {
            anyhow::bail!("--samples must be at least 2");
        }
        // The flags alone, before the model file is read (the defaults are in bounds).
        args.render_options(RenderOptions::default(), &args.model)?;
        // Judged against a band trained sampler: a stratified model is checked once it is read.
        args.ray_sampler(RaySampler::Band {
            margin_m: DEFAULT_BAND_MARGIN_M,
            cell_m: DEFAULT_OCCUPANCY_CELL_M,
        })?;
        let path = &args.model;
        let file = ModelFile::read(path)?;
        let run = RunSettings::from_json(&file.header.run).with_context(|| {
            format!(
                "{}: header field `run`: not a nia-train run config",
                path.display()
            )
        })?;
        let backend = args.backend.unwrap_or(Backend::Flex);
        if let Some(trained) = run.train.backend.filter(|b| b.is_gpu()) {
            if args.backend.is_none() {
                eprintln!(
                    "{}: trained on {}; rendering on the CPU ({}); pass --backend {} for the GPU",
                    path.display(),
                    trained.name(),
                    backend.name(),
                    trained.name()
                );
            }
        }
        let device = open_device(backend, args.device)?;
        let mut model = file.load(path, &device)?;
        model.ray_sampler = args.ray_sampler(model.ray_sampler)?;
        Ok(LoadedModel {
            path: path.clone(),
            model,
            run,
            step: file.header.step,
            backend,
            device,
        })
    }

    /// The model's `[render]` setting with the command line's overrides, checked.
    pub fn render_options(&self, args: &ModelArgs) -> anyhow::Result<RenderOptions> {
        args.render_options(self.run.render, &self.path)
    }

    /// Renders and scores `items` of `split` of `data` with this model on its device
    /// ([`evaluate_images`]), calling `on_image` for each.
    pub fn evaluate(
        &self,
        data: &OpenedDataset,
        split: EvalSplit,
        items: &[EvalItem],
        options: EvalOptions,
        on_image: &mut dyn FnMut(EvaluatedImage<'_>) -> Result<(), EvalError>,
    ) -> Result<Vec<ImageResult>, EvalError> {
        evaluate_images(
            &self.model,
            data,
            split,
            items,
            options,
            &self.device,
            on_image,
        )
    }

    /// Samples per ray: the command line's, else the training setting.
    pub fn samples(&self, args: &ModelArgs) -> usize {
        args.samples.unwrap_or(self.run.train.samples)
    }

    /// Rays per chunk: `--chunk`, or the device's default for `samples` samples per ray and
    /// the `render` options ([`rays_per_chunk`]: more on a GPU).
    pub fn chunk(&self, args: &ModelArgs, samples: usize, render: &RenderOptions) -> usize {
        self.chunk_or_default(args.chunk, samples, render)
    }

    /// [`Self::chunk`] with the `--chunk` value `chunk` itself.
    pub fn chunk_or_default(
        &self,
        chunk: Option<usize>,
        samples: usize,
        render: &RenderOptions,
    ) -> usize {
        chunk.unwrap_or_else(|| rays_per_chunk(&self.device, samples, render))
    }

    /// The run's `[data]` section, at `root` and with the SMPL model `smpl` when given.
    pub fn data_config(&self, root: Option<&Path>, smpl: Option<&Path>) -> DataConfig {
        let mut data = self.run.data.clone();
        if let Some(root) = root {
            data.root = root.to_path_buf();
        }
        if let Some(smpl) = smpl {
            data.smpl_model = Some(smpl.to_path_buf());
        }
        data
    }

    /// Opens the subjects of `split` of `data` with the run's split protocol; a synthetic set
    /// other than the run's own (`--data` elsewhere) brings its own split (its `synth.json`),
    /// so a model trained on 8 synthetic people evaluates on a set of 4 from another seed.
    pub fn open_split(&self, data: &DataConfig, split: EvalSplit) -> anyhow::Result<OpenedDataset> {
        let open = || -> anyhow::Result<OpenedDataset> {
            let protocol = self.run.protocol_for(data)?;
            Ok(OpenedDataset::open_split(data, protocol, split)?)
        };
        let synthetic_without_description = self.run.synth.is_some()
            && data.protocol != ProtocolName::Subjects
            && !data.root.join(nia_data::synth::DESCRIPTION_FILE).is_file();
        open().with_context(|| {
            if synthetic_without_description {
                format!(
                    "opening the `{}` split: the model's split is its synthetic set's, and {} \
                     has no {} to give one; name the people to evaluate with --subjects \
                     (e.g. --subjects CoreView_4, and --input-views)",
                    split.name(),
                    data.root.display(),
                    nia_data::synth::DESCRIPTION_FILE
                )
            } else {
                format!("opening the `{}` split", split.name())
            }
        })
    }
}

/// The SMPL model for a dataset at `root`: `--smpl` if given, else the run config's
/// `data.smpl_model`, else `body_model.npz` of the synthetic layout (at `root` or its parent).
pub fn smpl_path(
    explicit: Option<&Path>,
    run: &RunSettings,
    root: &Path,
) -> anyhow::Result<PathBuf> {
    if let Some(p) = explicit {
        return Ok(p.to_path_buf());
    }
    if let Some(p) = &run.data.smpl_model {
        return Ok(p.clone());
    }
    let candidates = [
        root.join(nia_data::synth::BODY_MODEL_FILE),
        root.join("..").join(nia_data::synth::BODY_MODEL_FILE),
    ];
    candidates
        .iter()
        .find(|p| p.is_file())
        .cloned()
        .with_context(|| {
            format!(
                "no SMPL model: pass --smpl <SMPL_NEUTRAL.pkl or .npz> (looked for {} and {})",
                candidates[0].display(),
                candidates[1].display()
            )
        })
}

/// LPIPS on the command line: all three flags, or none (then the model's training setting,
/// `train.lpips`, where there is one).
#[derive(Args, Debug, Clone, Default)]
pub struct LpipsArgs {
    /// LPIPS network: alex or vgg (with --lpips-backbone and --lpips-heads).
    #[arg(long, requires_all = ["lpips_backbone", "lpips_heads"])]
    pub lpips_net: Option<LpipsNet>,
    /// The torchvision trunk: alexnet-owt-7be5be79.pth or vgg16-397923af.pth.
    #[arg(long, requires = "lpips_net")]
    pub lpips_backbone: Option<PathBuf>,
    /// The `lpips` package's heads: lpips/weights/v0.1/alex.pth or vgg.pth.
    #[arg(long, requires = "lpips_net")]
    pub lpips_heads: Option<PathBuf>,
}

impl LpipsArgs {
    /// The files of the flags, else `fallback`.
    pub fn files(&self, fallback: Option<&LpipsFiles>) -> Option<LpipsFiles> {
        match (&self.lpips_net, &self.lpips_backbone, &self.lpips_heads) {
            (Some(net), Some(backbone), Some(heads)) => Some(LpipsFiles {
                net: *net,
                backbone: backbone.clone(),
                heads: heads.clone(),
                widths: None,
            }),
            _ => fallback.cloned(),
        }
    }

    /// Loads the metric of [`Self::files`] onto `device`.
    pub fn load(
        &self,
        fallback: Option<&LpipsFiles>,
        device: &Device,
    ) -> anyhow::Result<Option<(LpipsFiles, Arc<Lpips>)>> {
        let Some(files) = self.files(fallback) else {
            return Ok(None);
        };
        let lpips = files
            .load(device)
            .with_context(|| format!("loading LPIPS ({})", files.net.name()))?;
        Ok(Some((files, Arc::new(lpips))))
    }
}

/// The device `index` (which GPU; `None`: the default) of `backend`, with the backend's
/// start-up note on stderr.
pub fn open_device(backend: Backend, index: Option<usize>) -> anyhow::Result<Device> {
    let device = DeviceSpec { backend, index }.device()?;
    if let Some(note) = backend.start_up_note() {
        eprintln!("{note}");
    }
    Ok(device)
}
