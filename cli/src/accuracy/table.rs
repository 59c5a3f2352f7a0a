//! The report as text (`vkrt bench accuracy` without `--json`): every group's points, the
//! front marked, then the recommendations.

use std::fmt;

use super::AccuracyReport;

impl fmt::Display for AccuracyReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "{} ({})", self.device, self.driver)?;
        writeln!(
            f,
            "{}: {} primary, {} shadow, {} mirror rays; {:.0} s{}",
            self.mesh,
            self.rays.primary,
            self.rays.shadow,
            self.rays.secondary,
            self.wall_s,
            if self.quick { ", --quick" } else { "" }
        )?;
        for note in &self.notes {
            writeln!(f, "note: {note}")?;
        }
        for g in &self.groups {
            writeln!(
                f,
                "\n{} — time: {}; error: {}",
                g.title, g.time_axis, g.error_axis
            )?;
            for (i, p) in g.points.iter().enumerate() {
                let mark = if g.front.contains(&i) { '*' } else { ' ' };
                writeln!(
                    f,
                    " {mark} {:<44} {:>10.2} ms  error {:>10.4}{}",
                    p.setting,
                    p.time_ms,
                    p.error,
                    p.note
                        .as_ref()
                        .map_or(String::new(), |n| format!("  [{n}]"))
                )?;
            }
        }
        writeln!(f, "\n* on the Pareto front\n\nRecommendations:")?;
        for r in &self.recommendations {
            writeln!(
                f,
                "  {:<28} {:<32} {}: {}",
                r.use_case, r.group, r.setting, r.why
            )?;
        }
        Ok(())
    }
}
