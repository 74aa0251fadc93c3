//! Conversions between the wire types and the renderer's, written once: every crate that
//! speaks the protocol uses these, so a value cannot mean one thing to the coordinator and
//! another to a worker.

use tessera_render::{PixelRect, Strategy};

use crate::v1 as pb;

impl From<PixelRect> for pb::Rect {
    fn from(r: PixelRect) -> Self {
        Self {
            x0: r.x0,
            y0: r.y0,
            width: r.width,
            height: r.height,
        }
    }
}

impl From<pb::Rect> for PixelRect {
    fn from(r: pb::Rect) -> Self {
        Self {
            x0: r.x0,
            y0: r.y0,
            width: r.width,
            height: r.height,
        }
    }
}

impl From<Strategy> for pb::Strategy {
    fn from(s: Strategy) -> Self {
        match s {
            Strategy::Mis => Self::Mis,
            Strategy::Bsdf => Self::Bsdf,
            Strategy::Nee => Self::Nee,
        }
    }
}

/// A strategy number this build does not know (from a newer peer).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("unknown strategy {0}")]
pub struct UnknownStrategy(pub i32);

/// The strategy a message's `strategy` field names; unset means MIS, as the protocol says. An
/// unknown number is an error, never some other strategy: that would render other bits as if
/// they were the job's.
pub fn strategy_from_wire(v: i32) -> Result<Strategy, UnknownStrategy> {
    match pb::Strategy::try_from(v) {
        Ok(pb::Strategy::Unspecified | pb::Strategy::Mis) => Ok(Strategy::Mis),
        Ok(pb::Strategy::Bsdf) => Ok(Strategy::Bsdf),
        Ok(pb::Strategy::Nee) => Ok(Strategy::Nee),
        Err(_) => Err(UnknownStrategy(v)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strategies_and_rects_round_trip_and_unknown_values_are_errors() {
        for s in [Strategy::Mis, Strategy::Bsdf, Strategy::Nee] {
            assert_eq!(strategy_from_wire(pb::Strategy::from(s) as i32), Ok(s));
        }
        assert_eq!(strategy_from_wire(0), Ok(Strategy::Mis));
        assert_eq!(strategy_from_wire(99), Err(UnknownStrategy(99)));
        let r = PixelRect {
            x0: 1,
            y0: 2,
            width: 3,
            height: 4,
        };
        assert_eq!(PixelRect::from(pb::Rect::from(r)), r);
    }
}
