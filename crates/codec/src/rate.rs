//! Rate control: the best setting of a coding whose frame fits a byte
//! budget.
//!
//! A coding's setting (a lossy codec's quality, a segmentation's levels) is
//! an integer whose frames grow with it, as does their fidelity; so the
//! best frame within a budget is the one of the largest setting that fits,
//! found by bisection in a logarithmic number of encodings. Frame sizes are
//! not strictly monotone in a codec's quality, so a bisection may miss a
//! larger fitting setting beside a non-fitting one; the frame it returns
//! always fits. A budget below the smallest setting's frame is
//! [`CodecError::BudgetTooSmall`], which names that frame's size.

use std::ops::RangeInclusive;

use crate::CodecError;

/// The setting chosen, and its encoded frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Fitted<T> {
    /// The setting.
    pub setting: u8,
    /// The whole encoded frame (at most the budget).
    pub bytes: Vec<u8>,
    /// What the encoder returned beside the bytes (e.g. the views sent).
    pub extra: T,
}

/// The largest setting in `settings` whose frame, as `encode` makes it,
/// takes at most `budget` bytes. `encode` returns the frame's bytes and
/// anything the caller wants back for the chosen setting.
pub fn fit<T, E: From<CodecError>>(
    settings: RangeInclusive<u8>,
    budget: usize,
    mut encode: impl FnMut(u8) -> Result<(Vec<u8>, T), E>,
) -> Result<Fitted<T>, E> {
    let (mut lo, mut hi) = (*settings.start(), *settings.end());
    let (bytes, extra) = encode(lo)?;
    if bytes.len() > budget {
        return Err(CodecError::BudgetTooSmall {
            budget,
            minimum: bytes.len(),
        }
        .into());
    }
    let mut best = Fitted {
        setting: lo,
        bytes,
        extra,
    };
    // Invariant: `lo` fits (its frame is `best`); settings above `hi` do not.
    while lo < hi {
        let mid = lo + (hi - lo).div_ceil(2);
        let (bytes, extra) = encode(mid)?;
        if bytes.len() <= budget {
            lo = mid;
            best = Fitted {
                setting: mid,
                bytes,
                extra,
            };
        } else {
            hi = mid - 1;
        }
    }
    Ok(best)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(setting: u8) -> Result<(Vec<u8>, ()), CodecError> {
        Ok((vec![0; 100 + 10 * setting as usize], ()))
    }

    #[test]
    fn the_largest_fitting_setting_is_chosen() {
        for budget in [100, 105, 110, 555, 1100, 5000] {
            let f = fit(0..=100, budget, frame).unwrap();
            let want = ((budget - 100) / 10).min(100) as u8;
            assert_eq!(f.setting, want, "budget {budget}");
            assert!(f.bytes.len() <= budget);
        }
    }

    #[test]
    fn a_budget_below_the_smallest_frame_names_it() {
        assert_eq!(
            fit(3..=100, 129, frame),
            Err(CodecError::BudgetTooSmall {
                budget: 129,
                minimum: 130
            })
        );
    }
}
