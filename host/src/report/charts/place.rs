//! Placing point labels in pixel space: each label goes next to its point where it covers no
//! other label, no marker and nothing reserved, trying the eight sides of the point first and
//! then farther out (with a leader line back to the point).

/// A rectangle in pixels, `[x0, x1) × [y0, y1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Rect {
    pub x0: i32,
    pub y0: i32,
    pub x1: i32,
    pub y1: i32,
}

impl Rect {
    /// The rectangle of width `w` and height `h` whose top-left corner is `(x, y)`.
    pub(crate) fn at(x: i32, y: i32, w: i32, h: i32) -> Self {
        Self {
            x0: x,
            y0: y,
            x1: x + w,
            y1: y + h,
        }
    }

    /// The square of half side `r` around `(x, y)`.
    pub(crate) fn around((x, y): (i32, i32), r: i32) -> Self {
        Self {
            x0: x - r,
            y0: y - r,
            x1: x + r,
            y1: y + r,
        }
    }

    /// The area this rectangle shares with `o` [px²].
    pub(crate) fn overlap(&self, o: &Rect) -> i64 {
        let w = (self.x1.min(o.x1) - self.x0.max(o.x0)).max(0);
        let h = (self.y1.min(o.y1) - self.y0.max(o.y0)).max(0);
        i64::from(w) * i64::from(h)
    }

    /// Its area outside `bounds` [px²].
    fn outside(&self, bounds: &Rect) -> i64 {
        let area = i64::from(self.x1 - self.x0) * i64::from(self.y1 - self.y0);
        area - self.overlap(bounds)
    }

    /// The point of this rectangle nearest to `p` (where a leader line ends).
    pub(crate) fn nearest(&self, (x, y): (i32, i32)) -> (i32, i32) {
        (x.clamp(self.x0, self.x1), y.clamp(self.y0, self.y1))
    }
}

/// The free margin kept around a label [px].
const PAD: i32 = 3;

/// A placed label: its box and whether it sits away from its point (a leader line is drawn).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Placed {
    pub rect: Rect,
    pub leader: bool,
}

/// Places a label of size `sizes[i]` beside each point `anchors[i]`, in order (earlier labels
/// get the better places), inside `bounds`, covering as little as possible of the markers
/// (`marker` px around every anchor), of `reserved` and of the labels placed before.
pub(crate) fn place_labels(
    anchors: &[(i32, i32)],
    sizes: &[(u32, u32)],
    marker: i32,
    reserved: &[Rect],
    bounds: Rect,
) -> Vec<Placed> {
    let markers: Vec<Rect> = anchors.iter().map(|&a| Rect::around(a, marker)).collect();
    let mut taken: Vec<Rect> = reserved.to_vec();
    let mut out = Vec::with_capacity(anchors.len());
    for (i, (&(ax, ay), &(w, h))) in anchors.iter().zip(sizes).enumerate() {
        let (w, h) = (
            i32::try_from(w).unwrap_or(i32::MAX / 4),
            i32::try_from(h).unwrap_or(i32::MAX / 4),
        );
        let mut best: Option<(i64, Placed)> = None;
        'rings: for ring in 0..5 {
            let g = marker + 3 + ring * 14;
            // Right, left, above, below, then the four corners.
            let spots = [
                (ax + g, ay - h / 2),
                (ax - g - w, ay - h / 2),
                (ax - w / 2, ay - g - h),
                (ax - w / 2, ay + g),
                (ax + g, ay - g - h + h / 3),
                (ax + g, ay + g - h / 3),
                (ax - g - w, ay - g - h + h / 3),
                (ax - g - w, ay + g - h / 3),
            ];
            for (x, y) in spots {
                let rect = Rect::at(x, y, w, h);
                // Labels keep a few pixels apart: two labels touching read as one.
                let padded = Rect::at(x - PAD, y - PAD, w + 2 * PAD, h + 2 * PAD);
                let cost = rect.outside(&bounds) * 1000
                    + taken.iter().map(|t| padded.overlap(t) * 100).sum::<i64>()
                    + markers
                        .iter()
                        .enumerate()
                        .filter(|(j, _)| *j != i)
                        .map(|(_, m)| padded.overlap(m) * 100)
                        .sum::<i64>()
                    + i64::from(ring) * 40;
                let placed = Placed {
                    rect,
                    leader: ring > 0,
                };
                if best.is_none_or(|(c, _)| cost < c) {
                    best = Some((cost, placed));
                }
                if cost == i64::from(ring) * 40 {
                    // Nothing covered: the nearest free spot.
                    break 'rings;
                }
            }
        }
        let placed = best.map_or(
            Placed {
                rect: Rect::at(ax + marker + 3, ay - h / 2, w, h),
                leader: false,
            },
            |(_, p)| p,
        );
        taken.push(placed.rect);
        out.push(placed);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_of_close_points_do_not_overlap_and_stay_inside() {
        let bounds = Rect::at(0, 0, 600, 400);
        // A cluster of five points a few pixels apart, and one alone.
        let anchors = [
            (300, 200),
            (304, 203),
            (298, 206),
            (310, 199),
            (302, 195),
            (50, 50),
        ];
        let sizes = [(110, 14); 6];
        let placed = place_labels(&anchors, &sizes, 6, &[], bounds);
        for (i, a) in placed.iter().enumerate() {
            assert_eq!(a.rect.outside(&bounds), 0, "label {i} leaves the plot");
            for b in &placed[i + 1..] {
                let r = a.rect;
                let padded = Rect::at(
                    r.x0 - PAD,
                    r.y0 - PAD,
                    r.x1 - r.x0 + 2 * PAD,
                    r.y1 - r.y0 + 2 * PAD,
                );
                assert_eq!(padded.overlap(&b.rect), 0, "{a:?} touches {b:?}");
            }
        }
        // The lone point's label sits right beside it.
        assert_eq!(placed[5].rect, Rect::at(59, 43, 110, 14));
        assert!(!placed[5].leader);
        // A reserved box (a legend, a reference line's label) is avoided.
        let reserved = [Rect::at(55, 30, 200, 40)];
        let placed = place_labels(&[(50, 50)], &[(110, 14)], 6, &reserved, bounds);
        assert_eq!(placed[0].rect.overlap(&reserved[0]), 0);
    }
}
