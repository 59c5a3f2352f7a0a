//! Each group's Pareto front on (time, error), and the setting each use should pick, with a
//! sentence built from the measured numbers (never written by hand per setting).

use super::{KnobGroup, Point, Recommendation};

/// The uses a recommendation is made for; `KnobGroup::uses` names a subset.
pub const USES: [&str; 3] = [
    "interactive preview",
    "final frame",
    "physics/visibility queries",
];

/// The final frame accepts this much more error than the group's most accurate setting,
/// relative, so that a setting as accurate within noise but faster wins.
const FINAL_SLACK: f64 = 0.02;
/// ... and at least this much, absolute, so that an error of 0 still admits ties.
const FINAL_SLACK_MIN: f64 = 1e-12;

fn finite(p: &Point) -> bool {
    p.time_ms.is_finite() && p.error.is_finite()
}

/// Indices of the points no other point dominates on (`time_ms`, `error`), both minimized,
/// fastest first. Of exact duplicates only the first is kept; a point with a non-finite time
/// or error is never on the front (nor dominates one).
pub fn front(points: &[Point]) -> Vec<usize> {
    let dominates = |j: usize, i: usize| {
        let (a, b) = (&points[j], &points[i]);
        let no_worse = a.time_ms <= b.time_ms && a.error <= b.error;
        let better = a.time_ms < b.time_ms || a.error < b.error;
        no_worse && (better || j < i)
    };
    let mut out: Vec<usize> = (0..points.len())
        .filter(|&i| finite(&points[i]))
        .filter(|&i| !(0..points.len()).any(|j| j != i && finite(&points[j]) && dominates(j, i)))
        .collect();
    out.sort_by(|&a, &b| points[a].time_ms.total_cmp(&points[b].time_ms));
    out
}

/// Sets every group's `front`.
pub fn fill_fronts(groups: &mut [KnobGroup]) {
    for g in groups {
        g.front = front(&g.points);
    }
}

/// One recommendation per use and per group that lists the use, in [`USES`] order; a group
/// without a point of finite time and error gets none.
pub fn recommend(groups: &[KnobGroup]) -> Vec<Recommendation> {
    let mut out = Vec::new();
    for use_case in USES {
        for g in groups
            .iter()
            .filter(|g| g.uses.iter().any(|u| u == use_case))
        {
            if !g.points.iter().any(finite) {
                continue;
            }
            let g = &for_use(g, use_case);
            let (i, why) = match use_case {
                "interactive preview" => preview(g),
                "final frame" => final_frame(g),
                _ => physics(g),
            };
            out.push(Recommendation {
                use_case: use_case.to_string(),
                group: g.title.clone(),
                setting: g.points[i].setting.clone(),
                why,
            });
        }
    }
    out
}

/// `g` with every point's time the one `use_case` pays ([`super::UseTimes`]), where the
/// points carry one.
fn for_use(g: &KnobGroup, use_case: &str) -> KnobGroup {
    let mut g = g.clone();
    for p in &mut g.points {
        if let Some(u) = p.use_times {
            p.time_ms = u.of(use_case);
        }
    }
    g
}

/// The fastest point of `candidates` (ties: lower error, then the first).
fn fastest(points: &[Point], candidates: impl Iterator<Item = usize>) -> Option<usize> {
    candidates.min_by(|&a, &b| {
        let (pa, pb) = (&points[a], &points[b]);
        (pa.time_ms.total_cmp(&pb.time_ms))
            .then(pa.error.total_cmp(&pb.error))
            .then(a.cmp(&b))
    })
}

/// The most accurate finite point (ties: fastest). The group has one.
fn most_accurate(g: &KnobGroup) -> usize {
    let pts = &g.points;
    (0..pts.len())
        .filter(|&i| finite(&pts[i]))
        .min_by(|&a, &b| {
            (pts[a].error.total_cmp(&pts[b].error))
                .then(pts[a].time_ms.total_cmp(&pts[b].time_ms))
                .then(a.cmp(&b))
        })
        .expect("recommend skips groups without finite points")
}

/// `time, error (axis)`.
fn time_error(g: &KnobGroup, i: usize) -> String {
    let p = &g.points[i];
    format!(
        "{} ms, error {} ({})",
        fmt_num(p.time_ms),
        fmt_num(p.error),
        g.error_axis
    )
}

/// The fastest front point within the preview's error; else the most accurate.
fn preview(g: &KnobGroup) -> (usize, String) {
    let best = most_accurate(g);
    let within = front(&g.points)
        .into_iter()
        .find(|&i| g.points[i].error <= g.preview_error_max);
    let (i, head) = match within {
        Some(i) => (
            i,
            format!(
                "{}, within the preview's {}",
                time_error(g, i),
                fmt_num(g.preview_error_max)
            ),
        ),
        None => (
            best,
            format!(
                "{}; no setting is within the preview's {}",
                time_error(g, best),
                fmt_num(g.preview_error_max)
            ),
        ),
    };
    let tail = if i == best {
        "the most accurate".to_string()
    } else {
        let b = &g.points[best];
        format!(
            "the most accurate ({}) takes {} ms",
            b.setting,
            fmt_num(b.time_ms)
        )
    };
    (i, format!("{head}; {tail}"))
}

/// The fastest point within [`FINAL_SLACK`] of the lowest error.
fn final_frame(g: &KnobGroup) -> (usize, String) {
    let pts = &g.points;
    let e = pts[most_accurate(g)].error;
    let limit = e + (FINAL_SLACK * e).max(FINAL_SLACK_MIN);
    let i = fastest(
        pts,
        (0..pts.len()).filter(|&i| finite(&pts[i]) && pts[i].error <= limit),
    )
    .expect("the most accurate point is a candidate");
    let quick = fastest(pts, (0..pts.len()).filter(|&i| finite(&pts[i]))).expect("finite points");
    let head = format!(
        "{}, within {}% of the lowest error",
        time_error(g, i),
        FINAL_SLACK * 100.0
    );
    let why = if quick == i {
        format!("{head}; also the fastest")
    } else {
        format!(
            "{head}; the fastest ({}) takes {} ms with error {}",
            pts[quick].setting,
            fmt_num(pts[quick].time_ms),
            fmt_num(pts[quick].error)
        )
    };
    (i, why)
}

/// The fewest wrong answers (hard-case failures, and rays answered differently from the
/// reference setting), then the fastest; without hard cases, the final frame's.
fn physics(g: &KnobGroup) -> (usize, String) {
    let pts = &g.points;
    let timed = |i: &usize| pts[*i].time_ms.is_finite();
    let fails = |i: usize| {
        let a = &pts[i].accuracy;
        a.hard_cases
            .map(|h| h.failures() + a.hit_differences.unwrap_or(0))
    };
    let least = (0..pts.len()).filter(timed).filter_map(fails).min();
    let Some(least) = least else {
        let (i, why) = final_frame(g);
        return (i, format!("no setting ran the hard cases; {why}"));
    };
    let i = fastest(
        pts,
        (0..pts.len())
            .filter(timed)
            .filter(|&i| fails(i) == Some(least)),
    )
    .expect("a point has the least failures");
    let rays = pts[i].accuracy.hard_cases.map_or(0, |h| h.rays);
    let head = format!(
        "{} wrong answers ({} hard-case rays, and the reference's rays), {} ms",
        fmt_count(least),
        fmt_count(rays),
        fmt_num(pts[i].time_ms)
    );
    let quick = fastest(pts, (0..pts.len()).filter(timed)).expect("i is timed");
    let why = if pts[quick].time_ms >= pts[i].time_ms {
        format!("{head}; also the fastest")
    } else {
        let q = &pts[quick];
        let failures = match fails(quick) {
            Some(f) => format!("with {} wrong answers", fmt_count(f)),
            None => "(not run on the hard cases)".to_string(),
        };
        format!(
            "{head}; fastest overall ({}) {} ms {failures}",
            q.setting,
            fmt_num(q.time_ms)
        )
    };
    (i, why)
}

/// A measurement with three significant digits, trailing zeros dropped (`63`, `4.1`,
/// `0.0123`, `1.2e-5`); 0 and
/// non-finite values as they are.
pub(crate) fn fmt_num(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let mag = v.abs().log10().floor() as i32;
    if !(-4..6).contains(&mag) {
        let s = format!("{v:.2e}");
        let (mantissa, exp) = s.split_once('e').expect("{:e} has an exponent");
        return format!("{}e{exp}", trim_zeros(mantissa));
    }
    let decimals = (2 - mag).max(0) as usize;
    trim_zeros(&format!("{v:.decimals$}")).to_string()
}

/// `4.10` to `4.1`, `63.0` to `63`.
fn trim_zeros(s: &str) -> &str {
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.')
    } else {
        s
    }
}

/// A count with thousands separators (`123,456`).
pub(crate) fn fmt_count(n: u64) -> String {
    let s = n.to_string();
    let mut out = String::new();
    for (k, c) in s.chars().enumerate() {
        if k > 0 && (s.len() - k) % 3 == 0 {
            out.push(',');
        }
        out.push(c);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accuracy::{Accuracy, Costs, HardCases};

    fn p(setting: &str, time_ms: f64, error: f64) -> Point {
        Point {
            setting: setting.into(),
            time_ms,
            error,
            costs: Costs::default(),
            accuracy: Accuracy::default(),
            use_times: None,
            note: None,
        }
    }

    fn hard(mut pt: Point, failures: u64) -> Point {
        pt.accuracy.hard_cases = Some(HardCases {
            rays: 123_456,
            wrong_hits: failures,
            ..HardCases::default()
        });
        pt
    }

    fn group(points: Vec<Point>, uses: &[&str]) -> KnobGroup {
        KnobGroup {
            id: "g".into(),
            title: "G".into(),
            time_axis: "trace ms".into(),
            error_axis: "RMSE vs reference".into(),
            preview_error_max: 0.05,
            uses: uses.iter().map(|u| u.to_string()).collect(),
            points,
            front: Vec::new(),
        }
    }

    fn pick<'a>(recs: &'a [Recommendation], use_case: &str) -> &'a Recommendation {
        recs.iter().find(|r| r.use_case == use_case).unwrap()
    }

    #[test]
    fn front_drops_dominated_points_fastest_first() {
        let pts = [
            p("slow exact", 60.0, 0.0),
            p("dominated", 30.0, 0.2),
            p("fast", 5.0, 0.1),
            p("middle", 20.0, 0.01),
            p("same time worse", 20.0, 0.02),
            p("same error slower", 70.0, 0.0),
        ];
        assert_eq!(front(&pts), vec![2, 3, 0]);
    }

    #[test]
    fn front_keeps_the_first_of_duplicates() {
        let pts = [p("a", 1.0, 0.5), p("b", 1.0, 0.5), p("c", 2.0, 0.1)];
        assert_eq!(front(&pts), vec![0, 2]);
    }

    #[test]
    fn front_excludes_non_finite_points() {
        let pts = [
            p("nan error", 0.5, f64::NAN),
            p("inf time", f64::INFINITY, 0.0),
            p("ok", 3.0, 0.2),
            p("nan time", f64::NAN, 0.0),
        ];
        assert_eq!(front(&pts), vec![2]);
        assert!(front(&[p("nan", f64::NAN, f64::NAN)]).is_empty());
        assert!(front(&[]).is_empty());
    }

    #[test]
    fn fill_fronts_sets_each_group() {
        let mut gs = [
            group(vec![p("a", 2.0, 0.0), p("b", 1.0, 1.0)], &[]),
            group(vec![], &[]),
        ];
        fill_fronts(&mut gs);
        assert_eq!(gs[0].front, vec![1, 0]);
        assert!(gs[1].front.is_empty());
    }

    #[test]
    fn preview_takes_the_fastest_front_point_within_its_error() {
        let g = group(
            vec![
                p("exact", 63.0, 0.0),
                p("good", 4.1, 0.012),
                p("rough", 1.0, 0.3),
            ],
            &["interactive preview"],
        );
        let r = recommend(&[g]);
        assert_eq!(r.len(), 1);
        assert_eq!(r[0].setting, "good");
        assert_eq!(
            r[0].why,
            "4.1 ms, error 0.012 (RMSE vs reference), within the preview's 0.05; \
             the most accurate (exact) takes 63 ms"
        );
    }

    #[test]
    fn preview_falls_back_to_the_most_accurate_fastest_on_ties() {
        let g = group(
            vec![p("a", 9.0, 0.2), p("b", 3.0, 0.1), p("c", 2.0, 0.1)],
            &["interactive preview"],
        );
        let r = recommend(&[g]);
        assert_eq!(r[0].setting, "c");
        assert!(r[0].why.contains("no setting is within"), "{}", r[0].why);
        assert!(r[0].why.ends_with("the most accurate"), "{}", r[0].why);
    }

    #[test]
    fn final_frame_takes_the_fastest_within_two_percent_of_the_lowest_error() {
        let g = group(
            vec![
                p("best", 50.0, 0.100),
                p("near", 20.0, 0.1019),
                p("far", 10.0, 0.103),
            ],
            &["final frame"],
        );
        let r = recommend(&[g]);
        assert_eq!(r[0].setting, "near");
        assert!(
            r[0].why
                .contains("the fastest (far) takes 10 ms with error 0.103"),
            "{}",
            r[0].why
        );
        // An error of 0 admits only exact ties (within 1e-12).
        let g = group(
            vec![p("a", 9.0, 0.0), p("b", 5.0, 1e-13), p("c", 1.0, 1e-9)],
            &["final frame"],
        );
        assert_eq!(recommend(&[g])[0].setting, "b");
    }

    #[test]
    fn physics_takes_the_fewest_failures_then_the_fastest() {
        let g = group(
            vec![
                hard(p("robust slow", 20.0, 0.0), 0),
                hard(p("robust", 12.3, 0.1), 0),
                hard(p("leaky", 8.1, 0.0), 37),
                p("untested", 1.0, 0.0),
            ],
            &["physics/visibility queries"],
        );
        let r = recommend(&[g]);
        assert_eq!(r[0].setting, "robust");
        assert_eq!(
            r[0].why,
            "0 wrong answers (123,456 hard-case rays, and the reference's rays), 12.3 ms; fastest overall (untested) \
             1 ms (not run on the hard cases)"
        );
        let g = group(
            vec![
                hard(p("robust", 12.3, 0.1), 0),
                hard(p("leaky", 8.1, 0.0), 37),
            ],
            &["physics/visibility queries"],
        );
        assert!(recommend(&[g])[0]
            .why
            .ends_with("fastest overall (leaky) 8.1 ms with 37 wrong answers"));
    }

    #[test]
    fn each_use_ranks_by_the_time_it_pays() {
        // A quick build that traces slowly, and a slow build that traces fast.
        let timed = |name: &str, build: f64, trace: f64| Point {
            use_times: Some(crate::accuracy::UseTimes::new(build, trace)),
            ..hard(p(name, build + trace, 0.0), 0)
        };
        let g = group(
            vec![
                timed("fast build", 5.0, 10.0),
                timed("fast trace", 100.0, 2.0),
            ],
            &USES,
        );
        let r = recommend(&[g]);
        assert_eq!(pick(&r, "interactive preview").setting, "fast build");
        // 5 + 256·10 > 100 + 256·2; queries pay the trace alone.
        assert_eq!(pick(&r, "final frame").setting, "fast trace");
        assert_eq!(pick(&r, "physics/visibility queries").setting, "fast trace");
        assert!(pick(&r, "final frame").why.starts_with("612 ms"), "{:?}", r);
    }

    #[test]
    fn physics_without_hard_cases_uses_the_final_frame_rule() {
        let g = group(
            vec![p("a", 9.0, 0.0), p("b", 1.0, 0.5)],
            &["physics/visibility queries"],
        );
        let r = recommend(&[g]);
        assert_eq!(r[0].setting, "a");
        assert!(r[0].why.starts_with("no setting ran the hard cases"));
    }

    #[test]
    fn recommends_per_use_and_listed_group_skipping_empty_ones() {
        let all: Vec<&str> = USES.to_vec();
        let groups = [
            group(vec![p("x", 1.0, 0.0)], &all),
            group(vec![], &all),
            group(vec![p("nan", 1.0, f64::NAN)], &all),
            group(vec![p("y", 1.0, 0.0)], &["final frame"]),
        ];
        let r = recommend(&groups);
        let uses: Vec<_> = r
            .iter()
            .map(|r| (r.use_case.as_str(), r.setting.as_str()))
            .collect();
        assert_eq!(
            uses,
            [
                ("interactive preview", "x"),
                ("final frame", "x"),
                ("final frame", "y"),
                ("physics/visibility queries", "x"),
            ]
        );
        assert!(pick(&r, "final frame").why.ends_with("also the fastest"));
    }

    #[test]
    fn formats_numbers() {
        assert_eq!(fmt_num(63.0), "63");
        assert_eq!(fmt_num(4.1), "4.1");
        assert_eq!(fmt_num(12.34), "12.3");
        assert_eq!(fmt_num(1234.4), "1234");
        assert_eq!(fmt_num(0.0123), "0.0123");
        assert_eq!(fmt_num(0.0), "0");
        assert_eq!(fmt_num(-2.5), "-2.5");
        assert_eq!(fmt_num(1.2e-5), "1.2e-5");
        assert_eq!(fmt_num(f64::NAN), "NaN");
        assert_eq!(fmt_count(123_456), "123,456");
        assert_eq!(fmt_count(1_000), "1,000");
        assert_eq!(fmt_count(12), "12");
    }
}
