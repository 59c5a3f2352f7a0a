//! The robustness suite through the public API, on every structure and walk (the
//! kd-tree; the SAH BVH, the LBVH and PLOC, each with a stack and with the bitstack), each
//! built on the device as `vkrt trace` builds it: GPU tracer, default (watertight)
//! intersector, validation on.
//! Every case must report 0 failures on every structure of vkrt's; the
//! cases and what a failure is are documented in `vkrt::trace::robust`. The driver's own
//! structure (where the device has ray query) runs the same cases and has its failures
//! reported per case: Vulkan promises no watertight intersector. `vkrt bench
//! robustness` runs the same cases for both intersectors.

mod common;

use common::{assert_silent, context};
use vkrt::accel::device::{AccelChoice, AccelKind};
use vkrt::trace::robust::{run_group, run_group_with, CaseResult, Group, SuiteConfig, SuiteSize};
use vkrt::trace::Intersector;

fn check(group: Group, size: SuiteSize) {
    let Some(ctx) = context() else { return };
    let start = std::time::Instant::now();
    let mut results: Vec<CaseResult> = Vec::new();
    for accel in AccelChoice::all_on(&ctx) {
        results.extend(
            run_group(&ctx, group, &size, &[Intersector::Watertight], accel)
                .unwrap_or_else(|e| panic!("{group:?} on {}: {e}", accel.label())),
        );
    }
    report(&format!("{group:?}"), &results, start);
    assert_silent(&ctx);
}

/// Every group with each case's structure as the one bottom level of a top level (an
/// identity instance), the kd-tree and the BVHs each walked their own way: the two-level
/// walk must answer as the structure alone (0 failures).
#[test]
fn every_case_under_an_identity_instance() {
    let Some(ctx) = context() else { return };
    let start = std::time::Instant::now();
    let config = SuiteConfig {
        under_instance: true,
        ..SuiteConfig::default()
    };
    let mut results: Vec<CaseResult> = Vec::new();
    let choices = [
        AccelChoice::new(AccelKind::KdTree, Default::default()),
        AccelChoice::new(AccelKind::Lbvh, vkrt::accel::walk::Traversal::Bitstack),
        AccelChoice::new(AccelKind::Ploc, vkrt::accel::walk::Traversal::Wide),
    ];
    for group in Group::ALL {
        for accel in choices {
            results.extend(
                run_group_with(
                    &ctx,
                    group,
                    &SuiteSize::tiny(),
                    &[Intersector::Watertight],
                    accel,
                    &config,
                )
                .unwrap_or_else(|e| panic!("{group:?} on {}: {e}", accel.label())),
            );
        }
    }
    assert!(results
        .iter()
        .all(|r| r.accel.ends_with("under an instance")));
    report("every group under an instance", &results, start);
    assert_silent(&ctx);
}

/// Prints every case and asserts 0 failures on vkrt's structures.
fn report(group: &str, results: &[CaseResult], start: std::time::Instant) {
    assert!(!results.is_empty());
    for r in results {
        eprintln!(
            "{:<52} {:<17} {:>8} rays {:>6} {} ({} errors) {:>9.2} ms {}{}",
            r.case,
            r.accel,
            r.rays,
            r.failures,
            r.failure_kind,
            r.errors,
            r.trace_ms,
            r.note,
            if r.known_limit { " (known limit)" } else { "" }
        );
        for (ray, hit) in &r.examples {
            eprintln!("    failing ray {ray:?} -> {hit:?}");
        }
    }
    eprintln!("{group}: {:.1} s", start.elapsed().as_secs_f64());
    let driver = AccelKind::Driver.name();
    let driver_failures: u64 = results
        .iter()
        .filter(|r| r.accel == driver)
        .map(|r| r.failures)
        .sum();
    eprintln!("{group}: the driver's failures in all: {driver_failures}");
    for r in results {
        assert!(r.rays > 0, "{} on {}: no rays", r.case, r.accel);
        if r.accel == driver {
            continue;
        }
        // Known limitations are reported (vkrt bench robustness), and must not be errors.
        if r.known_limit {
            assert_eq!(r.errors, 0, "{} on {}: {r:?}", r.case, r.accel);
        } else {
            assert_eq!(r.failures, 0, "{} on {}: {r:?}", r.case, r.accel);
        }
    }
}

/// The suite's test sizes with smaller meshes: an 82K-triangle icosphere and a 200² grid
/// (the grid's rays aim at exact vertices, edges and cell centres whatever its size); at
/// quick sizes (the other drivers' legs), the smallest that still run every case
/// ([`SuiteSize::tiny`], what `vkrt bench accuracy --quick` runs).
fn size() -> SuiteSize {
    if common::quick() {
        return SuiteSize::tiny();
    }
    SuiteSize {
        sphere_subdivisions: 6,
        grid: 200,
        ..SuiteSize::test()
    }
}

#[test]
fn watertight_meshes_have_no_holes() {
    check(Group::Watertight, size());
}

#[test]
fn spawned_rays_never_rehit_their_surface() {
    check(Group::SelfIntersection, size());
}

#[test]
fn parallel_in_plane_and_boundary_rays_equal_brute_force() {
    check(Group::Rays, size());
}

#[test]
fn degenerate_geometry_never_hits_and_ties_are_deterministic() {
    check(Group::Degenerate, size());
}

#[test]
fn builder_stress_terminates_and_validates() {
    check(Group::Builder, size());
}

#[test]
fn bad_rays_miss() {
    check(Group::BadRays, size());
}
