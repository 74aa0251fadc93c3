//! Frame ranges: the frames of an animation a job renders, `first-last[:step]` as farm users
//! write them (`1-240`, `1-240:2`, or one frame `7`).

use std::fmt;
use std::str::FromStr;

/// Frames `first`, `first + step`, … up to `last` inclusive (`last` itself only where the step
/// lands on it).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct FrameRange {
    /// First frame.
    pub first: u32,
    /// Last frame asked for.
    pub last: u32,
    /// Distance between frames, at least 1.
    pub step: u32,
}

/// A frame range that is not one.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BadFrameRange {
    /// Not of the form `first-last[:step]`.
    #[error(
        "frames {0:?} must be FIRST-LAST or FIRST-LAST:STEP (e.g. 1-240 or 1-240:2), or one frame"
    )]
    Syntax(String),
    /// Runs backwards.
    #[error("frames {first}-{last}: the last frame is before the first")]
    Backwards {
        /// First frame.
        first: u32,
        /// Last frame.
        last: u32,
    },
    /// A step of 0.
    #[error("frames: the step must be at least 1")]
    ZeroStep,
}

impl FrameRange {
    /// Checks the range.
    pub fn new(first: u32, last: u32, step: u32) -> Result<Self, BadFrameRange> {
        if step == 0 {
            return Err(BadFrameRange::ZeroStep);
        }
        if last < first {
            return Err(BadFrameRange::Backwards { first, last });
        }
        Ok(Self { first, last, step })
    }

    /// Number of frames.
    pub fn len(&self) -> u64 {
        u64::from(self.last.saturating_sub(self.first) / self.step.max(1)) + 1
    }

    /// Never empty: a range holds its first frame.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// The frames, in order.
    pub fn iter(&self) -> impl Iterator<Item = u32> {
        let step = self.step.max(1) as usize;
        (self.first..=self.last).step_by(step)
    }
}

impl FromStr for FrameRange {
    type Err = BadFrameRange;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let syntax = || BadFrameRange::Syntax(s.chars().take(40).collect());
        let number = |t: &str| {
            // Digits only: `u32::from_str` also takes a leading '+'.
            if t.is_empty() || !t.bytes().all(|b| b.is_ascii_digit()) {
                return Err(syntax());
            }
            t.parse::<u32>().map_err(|_| syntax())
        };
        let (span, step) = match s.split_once(':') {
            Some((span, step)) => (span, number(step)?),
            None => (s, 1),
        };
        let (first, last) = match span.split_once('-') {
            Some((a, b)) => (number(a)?, number(b)?),
            None => {
                let f = number(span)?;
                (f, f)
            }
        };
        Self::new(first, last, step)
    }
}

impl fmt::Display for FrameRange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}-{}", self.first, self.last)?;
        if self.step != 1 {
            write!(f, ":{}", self.step)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_parse_as_farm_users_write_them() {
        let r: FrameRange = "1-240".parse().expect("range");
        assert_eq!((r.first, r.last, r.step, r.len()), (1, 240, 1, 240));
        let r: FrameRange = "1-10:4".parse().expect("range");
        assert_eq!(r.iter().collect::<Vec<_>>(), [1, 5, 9]);
        assert_eq!(r.len(), 3);
        assert_eq!(r.to_string(), "1-10:4");
        let r: FrameRange = "7".parse().expect("one frame");
        assert_eq!(r.iter().collect::<Vec<_>>(), [7]);
        let r: FrameRange = "0-4294967295:4294967295".parse().expect("extremes");
        assert_eq!(r.iter().collect::<Vec<_>>(), [0, u32::MAX]);
        assert_eq!(r.len(), 2);
    }

    #[test]
    fn bad_ranges_say_what_is_wrong() {
        for bad in [
            "",
            "-",
            "1-",
            "-5",
            "a-b",
            "1-2:",
            "+1-3",
            "1-2-3",
            "1-99999999999",
            "1:2:3",
        ] {
            let e = bad.parse::<FrameRange>().expect_err(bad);
            assert!(matches!(e, BadFrameRange::Syntax(_)), "{bad}: {e}");
            assert!(e.to_string().contains("FIRST-LAST"), "{e}");
        }
        assert_eq!(
            "9-3".parse::<FrameRange>(),
            Err(BadFrameRange::Backwards { first: 9, last: 3 })
        );
        assert_eq!("1-3:0".parse::<FrameRange>(), Err(BadFrameRange::ZeroStep));
    }
}
