//! Messages handed back after use, to be decoded over: a source that decodes (ROS 2)
//! takes its next message's buffers from its [`Recycler`], so that a warm stream of
//! messages of one size decodes without allocating (`msgs::decode_into`, serde's in-place
//! deserialisation); whoever is done with a message puts it back ([`Recycler::put`]),
//! on any thread.

use std::sync::{Arc, Mutex};

use serde::de::{DeserializeSeed, Deserializer};

use super::Message;

/// Messages kept at most (a consumer that puts back more frees the rest).
const KEPT: usize = 16;

/// Messages handed back to a source; see the module docs. Clones share the messages.
#[derive(Debug)]
pub struct Recycler<M>(Arc<Mutex<Vec<M>>>);

impl<M> Clone for Recycler<M> {
    fn clone(&self) -> Self {
        Self(self.0.clone())
    }
}

impl<M> Default for Recycler<M> {
    fn default() -> Self {
        Self(Arc::new(Mutex::new(Vec::new())))
    }
}

impl<M> Recycler<M> {
    /// Hands `message` back, to be decoded over (freed past [`KEPT`]).
    pub fn put(&self, message: M) {
        let mut kept = self.0.lock().unwrap_or_else(|e| e.into_inner());
        if kept.len() < KEPT {
            kept.push(message);
        }
    }

    /// A message handed back, if any.
    pub fn take(&self) -> Option<M> {
        self.0.lock().unwrap_or_else(|e| e.into_inner()).pop()
    }
}

/// Decodes a message over one handed back (else a new one).
pub(crate) struct Reuse<M>(pub(crate) Recycler<M>);

impl<M> Clone for Reuse<M> {
    fn clone(&self) -> Self {
        Self(self.0.clone())
    }
}

impl<'de, M: Message> DeserializeSeed<'de> for Reuse<M> {
    type Value = M;

    fn deserialize<D: Deserializer<'de>>(self, deserializer: D) -> Result<M, D::Error> {
        let mut message = self.0.take().unwrap_or_default();
        M::deserialize_in_place(deserializer, &mut message)?;
        Ok(message)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn at_most_a_few_messages_are_kept() {
        let r = Recycler::<posestream_msgs::HeatMaps>::default();
        for _ in 0..100 {
            r.clone().put(posestream_msgs::HeatMaps::default());
        }
        let mut n = 0;
        while r.take().is_some() {
            n += 1;
        }
        assert_eq!(n, KEPT);
    }
}
