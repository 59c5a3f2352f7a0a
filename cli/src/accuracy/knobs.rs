//! The knobs `vkrt bench accuracy` turns, in groups; each group is plotted on its own time
//! and error axes (see [`super::measure`] for what is measured of each kind of setting).

use vkrt::accel::bvh::lbvh::MortonBits;
use vkrt::accel::bvh::ploc::PlocParams;
use vkrt::accel::bvh::BvhParams;
use vkrt::accel::device::{AccelBuilder, AccelChoice, AccelKind};
use vkrt::accel::driver::Prefer;
use vkrt::accel::kdtree::SahParams;
use vkrt::accel::walk::Traversal;
use vkrt::gpu::{Context, Result};
use vkrt::render::gpu::Update;
use vkrt::trace::{Intersector, TraceOptions};

/// How a structure setting's structure is made.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Build {
    /// By an [`AccelBuilder`] of `choice.kind` with these parameters (the device builders,
    /// the host SAH BVH, the driver's).
    Builder {
        /// The structure kind and the walk kernels trace it with.
        choice: AccelChoice,
        /// The kd-tree builder's SAH parameters and termination.
        kd: SahParams,
        /// The SAH BVH builder's parameters.
        bvh: BvhParams,
        /// The LBVH's Morton code bits (LBVH only).
        bits: MortonBits,
        /// PLOC's parameters (PLOC only; `None`: its defaults).
        ploc: Option<PlocParams>,
    },
    /// The host kd-tree with full clipping (`accel::kdtree::full_clip`), uploaded: the
    /// quality reference Kolodzey's split-axis clipping is measured against.
    KdFullClip(SahParams),
}

impl Build {
    /// `choice` built with every parameter at its default.
    pub fn default_for(choice: AccelChoice) -> Self {
        Build::Builder {
            choice,
            kd: SahParams::default(),
            bvh: BvhParams::default(),
            bits: MortonBits::default(),
            ploc: None,
        }
    }

    /// The structure and walk kernels trace it as.
    pub fn choice(&self) -> AccelChoice {
        match *self {
            Build::Builder { choice, .. } => choice,
            Build::KdFullClip(_) => AccelChoice::new(AccelKind::KdTree, Traversal::Stack),
        }
    }

    /// The kd-tree parameters (defaults for other kinds).
    pub fn kd_params(&self) -> SahParams {
        match *self {
            Build::Builder { kd, .. } => kd,
            Build::KdFullClip(kd) => kd,
        }
    }

    /// The device builder of this setting (`None` for a host-only structure).
    pub fn builder(&self, ctx: &Context) -> Result<Option<AccelBuilder>> {
        let Build::Builder {
            choice,
            kd,
            bvh,
            bits,
            ploc,
        } = *self
        else {
            return Ok(None);
        };
        let mut b = match (choice.kind, ploc) {
            (AccelKind::Lbvh, _) => AccelBuilder::lbvh(ctx, bits)?,
            (AccelKind::Ploc, Some(p)) => AccelBuilder::ploc(ctx, p)?,
            _ => AccelBuilder::for_choice(ctx, choice)?,
        };
        b = b.with_driver_prefer(choice.prefer);
        b = b.with_kd_params(kd);
        b = b.with_bvh_params(bvh);
        Ok(Some(b))
    }
}

/// A setting that builds a structure and traces rays through it.
#[derive(Clone, Debug)]
pub struct StructureSetting {
    /// The setting's name in the report.
    pub label: String,
    /// How the structure is made.
    pub build: Build,
    /// Intersector, fp64 fallback, short-stack size (the query is the ray set's).
    pub trace: TraceOptions,
    /// Also render the image scenes with it (settings a render can express: the default
    /// parameters of a kind, a walk, a triangle test).
    pub render: bool,
}

/// A setting of the renderer: samples per pixel and bounces.
#[derive(Clone, Debug)]
pub struct ImageSetting {
    /// The setting's name in the report.
    pub label: String,
    /// Samples per pixel.
    pub spp: u32,
    /// Ray depth (bounces).
    pub depth: u32,
}

/// A setting of an animation: a BVH kind kept up to date by a refit or a rebuild.
#[derive(Clone, Debug)]
pub struct MotionSetting {
    /// The setting's name in the report (`<kind> <update>`).
    pub label: String,
    /// The BVH kind.
    pub kind: AccelKind,
    /// Whether each frame refits or rebuilds it.
    pub update: Update,
}

/// What a group's settings are.
#[derive(Clone, Debug)]
pub enum Settings {
    /// Structures built over the bunny and traced.
    Structures(Vec<StructureSetting>),
    /// Renders of the image scenes, compared with their references.
    Images(Vec<ImageSetting>),
    /// Animations of the dynamic demo.
    Motion(Vec<MotionSetting>),
}

/// A group of knobs, before measuring.
#[derive(Clone, Debug)]
pub struct GroupSpec {
    /// Short id (`KnobGroup::id`).
    pub id: &'static str,
    /// Human-readable title (`KnobGroup::title`).
    pub title: &'static str,
    /// The settings to measure.
    pub settings: Settings,
}

/// How much the run measures.
#[derive(Clone, Copy, Debug)]
pub struct Sizes {
    /// Width of the bunny's primary-ray image (square).
    pub ray_image: u32,
    /// The image scenes' width in pixels.
    pub width: u32,
    /// The image scenes' height in pixels.
    pub height: u32,
    /// The reference's samples per pixel and depth.
    pub reference_spp: u32,
    /// The reference's ray depth, also the structure and spp settings' depth.
    pub reference_depth: u32,
    /// Samples per pixel of the structure settings' images and of the depth group.
    pub test_spp: u32,
    /// Frames of the motion group, every `frame_step`-th of the animation.
    pub frames: u32,
    /// Animation frames between two measured frames.
    pub frame_step: u32,
    /// The motion group's render width in pixels.
    pub motion_width: u32,
    /// The motion group's render height in pixels.
    pub motion_height: u32,
    /// Timed repetitions of builds and traces (the best is kept).
    pub reps: u32,
}

impl Sizes {
    /// The sizes of a full run, or smaller ones with `quick`.
    pub fn new(quick: bool) -> Self {
        if quick {
            Self {
                ray_image: 128,
                width: 96,
                height: 72,
                reference_spp: 64,
                reference_depth: 8,
                test_spp: 4,
                frames: 3,
                frame_step: 12,
                motion_width: 128,
                motion_height: 96,
                reps: 1,
            }
        } else {
            Self {
                ray_image: 512,
                width: 256,
                height: 192,
                reference_spp: 1024,
                reference_depth: 8,
                test_spp: 16,
                frames: 8,
                frame_step: 6,
                motion_width: 512,
                motion_height: 384,
                reps: 3,
            }
        }
    }
}

fn structure(label: impl Into<String>, build: Build, render: bool) -> StructureSetting {
    StructureSetting {
        label: label.into(),
        build,
        trace: TraceOptions::default(),
        render,
    }
}

fn kd(params: SahParams) -> Build {
    Build::Builder {
        choice: AccelChoice::new(AccelKind::KdTree, Traversal::Stack),
        kd: params,
        bvh: BvhParams::default(),
        bits: MortonBits::default(),
        ploc: None,
    }
}

fn bvh_kind(kind: AccelKind, walk: Traversal, bvh: BvhParams) -> Build {
    Build::Builder {
        choice: AccelChoice::new(kind, walk),
        kd: SahParams::default(),
        bvh,
        bits: MortonBits::default(),
        ploc: None,
    }
}

/// Kolodzey's (2014) termination: leaves below 64 primitives, no SAH leaf test.
pub fn kolodzey_termination() -> SahParams {
    SahParams {
        sah_leaf_test: false,
        max_leaf_prims: 63,
        ..SahParams::default()
    }
}

/// The groups, smaller with `quick`; the driver's structures where `ctx` has ray query.
pub fn groups(ctx: &Context, quick: bool) -> Vec<GroupSpec> {
    let pick = |full: &[u32], q: &[u32]| if quick { q.to_vec() } else { full.to_vec() };
    let stack = Traversal::Stack;

    // Structures: every builder and its main parameter.
    let mut structures = vec![
        structure(
            "kd-tree (Wu et al. 2011: split-axis clipping)",
            kd(SahParams::default()),
            true,
        ),
        structure(
            "kd-tree, full clipping (host)",
            Build::KdFullClip(SahParams::default()),
            false,
        ),
        structure(
            "SAH BVH, full sweep",
            bvh_kind(AccelKind::SahBvh, stack, BvhParams::default()),
            true,
        ),
    ];
    for bins in pick(&[8, 16, 32, 64, 256], &[8, 32, 256]) {
        let p = BvhParams {
            bins: Some(bins),
            ..BvhParams::default()
        };
        structures.push(structure(
            format!("SAH BVH, {bins} bins"),
            bvh_kind(AccelKind::SahBvh, stack, p),
            false,
        ));
    }
    for (bits, name) in [(MortonBits::Bits30, "30"), (MortonBits::Bits63, "63")] {
        structures.push(structure(
            format!("LBVH, {name}-bit Morton codes"),
            Build::Builder {
                choice: AccelChoice::new(AccelKind::Lbvh, stack),
                kd: SahParams::default(),
                bvh: BvhParams::default(),
                bits,
                ploc: None,
            },
            bits == MortonBits::default(),
        ));
    }
    for radius in pick(&[4, 8, 16], &[4, 16]) {
        let ploc = PlocParams {
            radius,
            ..PlocParams::default()
        };
        structures.push(structure(
            format!("PLOC, r = {radius}"),
            Build::Builder {
                choice: AccelChoice::new(AccelKind::Ploc, stack),
                kd: SahParams::default(),
                bvh: BvhParams::default(),
                bits: ploc.bits,
                ploc: Some(ploc),
            },
            radius == PlocParams::default().radius,
        ));
    }
    if ctx.info().features.ray_query {
        for prefer in [Prefer::FastTrace, Prefer::FastBuild] {
            let c = AccelChoice::driver(prefer);
            structures.push(structure(
                format!("driver ({})", c.label()),
                Build::default_for(c),
                prefer == Prefer::FastTrace,
            ));
        }
    }

    // kd-tree termination.
    let mut termination = vec![
        structure(
            "SAH leaf test, leaves <= 2 (default)",
            kd(SahParams::default()),
            false,
        ),
        structure(
            "Kolodzey 2014: leaves < 64, no SAH leaf test",
            kd(kolodzey_termination()),
            false,
        ),
    ];
    for depth in pick(&[12, 16, 24], &[12]) {
        termination.push(structure(
            format!("depth limit {depth}"),
            kd(SahParams {
                max_depth: Some(depth),
                ..SahParams::default()
            }),
            false,
        ));
    }

    // BVH leaf size (the SAH BVH's largest leaf the SAH may choose).
    let leaves = pick(&[1, 2, 4, 8, 16], &[1, 4, 16])
        .into_iter()
        .map(|n| {
            let p = BvhParams {
                max_leaf_prims: n,
                ..BvhParams::default()
            };
            structure(
                format!("SAH BVH, leaves <= {n}"),
                bvh_kind(AccelKind::SahBvh, stack, p),
                false,
            )
        })
        .collect();

    // Traversal: the BVH's stack and the bitstack (Áfra & Szirmay-Kalos 2014); the kd-tree's short stack.
    let mut traversal = vec![
        structure(
            "SAH BVH, stack",
            bvh_kind(AccelKind::SahBvh, stack, BvhParams::default()),
            true,
        ),
        structure(
            "SAH BVH, bitstack (Áfra & Szirmay-Kalos 2014)",
            bvh_kind(AccelKind::SahBvh, Traversal::Bitstack, BvhParams::default()),
            true,
        ),
    ];
    for entries in pick(&[4, 8, 16, 32, 64], &[4, 32]) {
        traversal.push(StructureSetting {
            label: format!("kd-tree, short stack of {entries}"),
            build: kd(SahParams::default()),
            trace: TraceOptions {
                stack_size: entries,
                ..TraceOptions::default()
            },
            render: false,
        });
    }

    // Intersector, on the kd-tree.
    let intersector = [
        ("watertight + fp64 fallback", Intersector::Watertight, true),
        ("watertight, no fp64", Intersector::Watertight, false),
        ("Möller–Trumbore", Intersector::MollerTrumbore, false),
    ]
    .into_iter()
    .map(|(label, intersector, exact)| StructureSetting {
        label: label.into(),
        build: kd(SahParams::default()),
        trace: TraceOptions {
            intersector,
            exact,
            ..TraceOptions::default()
        },
        render: true,
    })
    .collect();

    let sizes = Sizes::new(quick);
    let spp = pick(&[1, 4, 16, 64, 256], &[1, 4, 16])
        .into_iter()
        .map(|spp| ImageSetting {
            label: format!("{spp} spp"),
            spp,
            depth: sizes.reference_depth,
        })
        .collect();
    let depth = pick(&[1, 2, 3, 4, 6, 8], &[1, 2, 4, 8])
        .into_iter()
        .map(|depth| ImageSetting {
            label: format!("depth {depth}"),
            spp: sizes.test_spp,
            depth,
        })
        .collect();

    let mut motion = Vec::new();
    for kind in [AccelKind::SahBvh, AccelKind::Lbvh, AccelKind::Ploc] {
        for update in [Update::Rebuild, Update::Refit] {
            motion.push(MotionSetting {
                label: format!("{} {}", kind.name(), update.name()),
                kind,
                update,
            });
        }
    }

    vec![
        GroupSpec {
            id: "structure",
            title: "Structure and builder",
            settings: Settings::Structures(structures),
        },
        GroupSpec {
            id: "kd-termination",
            title: "kd-tree termination",
            settings: Settings::Structures(termination),
        },
        GroupSpec {
            id: "bvh-leaf",
            title: "BVH leaf size",
            settings: Settings::Structures(leaves),
        },
        GroupSpec {
            id: "traversal",
            title: "Traversal",
            settings: Settings::Structures(traversal),
        },
        GroupSpec {
            id: "intersector",
            title: "Ray/triangle test",
            settings: Settings::Structures(intersector),
        },
        GroupSpec {
            id: "spp",
            title: "Samples per pixel",
            settings: Settings::Images(spp),
        },
        GroupSpec {
            id: "depth",
            title: "Ray depth",
            settings: Settings::Images(depth),
        },
        GroupSpec {
            id: "refit",
            title: "Refit vs rebuild after motion",
            settings: Settings::Motion(motion),
        },
    ]
}
