//! Following a session's frames in file order: [`FrameWindow`] (the recent frames a `/pairs`
//! record names) and [`SessionSequences`] (frame numbers that keep increasing across a
//! device restart).

use crate::frame::StreamKind;

/// The last frames of one stream as read from a session, for looking up the frames a `/pairs`
/// record names. Bounded and keyed by *arrival*, not by sequence: after a device reopen the
/// sequence restarts at 0, so evicting the smallest sequence (a map's first key) would throw
/// away the newest frames. A lookup returns the newest frame with that sequence (a pair
/// record follows its frames closely).
#[derive(Debug, Clone)]
pub struct FrameWindow<T> {
    capacity: usize,
    frames: std::collections::VecDeque<(u32, T)>,
}

impl<T> Default for FrameWindow<T> {
    fn default() -> Self {
        Self::new(Self::DEFAULT_CAPACITY)
    }
}

impl<T> FrameWindow<T> {
    /// Pairs are decided within a few frames; 512 covers seconds of the fastest stream.
    pub const DEFAULT_CAPACITY: usize = 512;

    pub fn new(capacity: usize) -> Self {
        Self {
            capacity: capacity.max(1),
            frames: std::collections::VecDeque::new(),
        }
    }

    /// Adds the newest frame, forgetting the oldest beyond the capacity.
    pub fn push(&mut self, sequence: u32, frame: T) {
        if self.frames.len() == self.capacity {
            self.frames.pop_front();
        }
        self.frames.push_back((sequence, frame));
    }

    /// The newest frame with this sequence.
    pub fn get(&self, sequence: u32) -> Option<&T> {
        self.frames
            .iter()
            .rev()
            .find(|(s, _)| *s == sequence)
            .map(|(_, f)| f)
    }

    pub fn len(&self) -> usize {
        self.frames.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }
}

/// Numbers each stream's frames in file order: the recorded sequence while it increases,
/// continued (last + 1, …) when it goes back, as after a device reopen. Deterministic, so the
/// scan and every later read of the same file agree. Feed it every frame of the file.
#[derive(Debug, Clone, Copy, Default)]
pub struct SessionSequences {
    /// Per stream (thermal, RGB): the last recorded sequence and the number it was given.
    last: [Option<(u32, u32)>; 2],
    /// Added to recorded sequences since the last restart.
    offset: [u32; 2],
}

impl SessionSequences {
    /// The session sequence of the next frame of `stream` recorded with `sequence`.
    pub fn next(&mut self, stream: StreamKind, sequence: u32) -> u32 {
        let k = usize::from(stream == StreamKind::Rgb);
        if let Some((raw, given)) = self.last[k]
            && sequence <= raw
        {
            self.offset[k] = given.saturating_add(1).saturating_sub(sequence);
        }
        let id = sequence.saturating_add(self.offset[k]);
        self.last[k] = Some((sequence, id));
        id
    }
}
