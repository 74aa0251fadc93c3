//! What the commands write to a terminal, made safe and legible there: progress bars that
//! keep their width, and names from others (workers', scenes') escaped so that they cannot
//! drive the terminal.

/// A progress bar style that fits an 80-column terminal: the bar keeps a fixed width and the
/// message (`tail`, which must contain `{wide_msg}`) is cut to what is left, rather than the
/// message pushing the bar down to nothing.
pub(crate) fn progress_style(tail: &str) -> indicatif::ProgressStyle {
    indicatif::ProgressStyle::with_template(&format!(
        "{{spinner}} [{{elapsed_precise}}] {{bar:24}} {tail}"
    ))
    .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
}

/// `s` with control characters (escape sequences, carriage returns) and Unicode's invisible
/// format characters (bidirectional overrides such as U+202E, zero-width spaces, the line and
/// paragraph separators U+2028 and U+2029) written as escapes: for names that came from
/// someone else (a worker's, a scene's), which must not be able to move the cursor, recolour
/// the terminal, or make one name read as another for whoever lists them.
pub(crate) fn printable(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_control() || is_format_or_separator(c) {
                c.escape_default().to_string()
            } else {
                c.to_string()
            }
        })
        .collect()
}

/// Whether `c` is in Unicode's general category Cf (format), Zl or Zp (Unicode 15.1's table;
/// none of them has a visible glyph of its own).
fn is_format_or_separator(c: char) -> bool {
    matches!(
        u32::from(c),
        0xAD | 0x600..=0x605
            | 0x61C
            | 0x6DD
            | 0x70F
            | 0x890..=0x891
            | 0x8E2
            | 0x180E
            | 0x200B..=0x200F
            | 0x2028..=0x202E
            | 0x2060..=0x2064
            | 0x2066..=0x206F
            | 0xFEFF
            | 0xFFF9..=0xFFFB
            | 0x110BD
            | 0x110CD
            | 0x13430..=0x1343F
            | 0x1BCA0..=0x1BCA3
            | 0x1D173..=0x1D17A
            | 0xE0001
            | 0xE0020..=0xE007F
    )
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_progress_bar_keeps_its_width_at_80_columns() {
        use indicatif::{InMemoryTerm, ProgressBar, ProgressDrawTarget};
        let term = InMemoryTerm::new(4, 80);
        let bar = ProgressBar::with_draw_target(
            Some(100),
            ProgressDrawTarget::term_like(Box::new(term.clone())),
        );
        bar.set_style(super::progress_style("{percent:>3}% {wide_msg}"));
        bar.set_message(
            "running 1234/5678 units, 12.34 Msamples/s, noise 1.23%, ETA 1h02m, and then some",
        );
        bar.set_position(50);
        bar.tick();
        let screen = term.contents();
        let line = screen.lines().next().unwrap_or_default();
        assert!(line.chars().count() <= 80, "{line:?}");
        assert!(line.contains(" 50%"), "{line:?}");
        let filled = line.chars().filter(|&c| c == '█').count();
        assert_eq!(filled, 12, "half of a 24-column bar: {line:?}");
    }

    #[test]
    fn names_from_others_cannot_drive_the_terminal() {
        assert_eq!(super::printable("w\u{1b}[2J\rx"), "w\\u{1b}[2J\\rx");
        assert_eq!(super::printable("rendu-é"), "rendu-é");
        // A right-to-left override would show "evil\u{202e}fdp.exr" as "evilrxe.pdf".
        assert_eq!(
            super::printable("a\u{202e}b\u{2028}c\u{200b}"),
            "a\\u{202e}b\\u{2028}c\\u{200b}"
        );
    }
}
