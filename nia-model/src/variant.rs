//! The paper's ablation variants (NIA Table 3.i), all trainable from one config switch.
//!
//! Serialised in lowercase snake case (`"no_body"`, `"no_ibr"`, `"simple_average"`,
//! `"cosine_weighted"`, `"full"`), so a run config reads `variant = "full"`.

use serde::{Deserialize, Serialize};

/// Which parts of the NIA network are active.
///
/// | variant | body feature s_n | colour c |
/// |---|---|---|
/// | (a) [`Variant::NoBody`] | no (Z = L) | F_B blend |
/// | (b) [`Variant::NoIbr`] | yes | c = c0 (F_B unused) |
/// | (c) [`Variant::SimpleAverage`] | yes | c = mean of [c0, c_1..c_N] |
/// | (d) [`Variant::CosineWeighted`] | yes | c = [c0, c_n] weighted ∝ [1, max(cos_n, 0)] |
/// | (e) [`Variant::Full`] | yes | F_B blend of [c0, c_1..c_N] |
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Variant {
    /// (a) No implicit body: the cross-attention is bypassed and Z = L (pixel features only).
    NoBody,
    /// (b) No image-based rendering: the colour is the NeRF colour c0.
    NoIbr,
    /// (c) The colour is the simple average of the colour predictions c0 and c_n.
    SimpleAverage,
    /// (d) The colour is the average of c0 and c_n weighted by the cosine between the target
    /// ray and each prediction's view direction (1 for c0, negative cosines count 0).
    CosineWeighted,
    /// (e) The full model.
    #[default]
    Full,
}

impl Variant {
    /// All five variants, in the paper's order (a)..(e).
    pub const ALL: [Variant; 5] = [
        Variant::NoBody,
        Variant::NoIbr,
        Variant::SimpleAverage,
        Variant::CosineWeighted,
        Variant::Full,
    ];

    /// Whether the body feature s_n and the view-wise cross-attention are used.
    pub fn uses_body(self) -> bool {
        !matches!(self, Variant::NoBody)
    }

    /// Whether the blending network F_B produces the colour (variants (a) and (e)).
    pub fn uses_blender(self) -> bool {
        matches!(self, Variant::NoBody | Variant::Full)
    }

    /// The name used in configs (`"no_body"`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Variant::NoBody => "no_body",
            Variant::NoIbr => "no_ibr",
            Variant::SimpleAverage => "simple_average",
            Variant::CosineWeighted => "cosine_weighted",
            Variant::Full => "full",
        }
    }
}

impl std::fmt::Display for Variant {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}
