//! Values computed from a mesh, remembered for the most recently seen meshes.
//!
//! The host geometry of a scene (the band sampler's occupancy grid, the nearest-surface index,
//! the body volume's sites and rulebooks) is a pure function of the posed mesh and a few
//! settings. Training draws its scenes from a few subjects and frames, evaluation renders several
//! views of each frame, and the loader's workers build a training scene's geometry ahead of the
//! step that needs it: a [`MeshMemo`] hands each of them the value built before for exactly
//! this mesh (compared bit for bit: every vertex coordinate, every face, every setting) or
//! builds and remembers it. The memo keeps its `capacity` most recently used values,
//! process-wide, behind a mutex; a build runs outside the lock.

use std::collections::VecDeque;
use std::hash::{Hash, Hasher};
use std::sync::{Arc, Mutex};

use glam::Vec3;

struct Entry<T> {
    hash: u64,
    settings: Vec<u32>,
    vertices: Vec<[u32; 3]>,
    faces: Vec<[u32; 3]>,
    value: Arc<T>,
}

/// The key of one lookup: the mesh's bits and the settings' bits.
struct Key<'a> {
    hash: u64,
    settings: &'a [u32],
    vertices: &'a [Vec3],
    faces: &'a [[u32; 3]],
}

impl<'a> Key<'a> {
    fn new(vertices: &'a [Vec3], faces: &'a [[u32; 3]], settings: &'a [u32]) -> Self {
        let mut h = std::collections::hash_map::DefaultHasher::new();
        (settings, vertices.len(), faces.len()).hash(&mut h);
        for v in vertices {
            bits(*v).hash(&mut h);
        }
        faces.hash(&mut h);
        Key {
            hash: h.finish(),
            settings,
            vertices,
            faces,
        }
    }
}

fn bits(v: Vec3) -> [u32; 3] {
    v.to_array().map(f32::to_bits)
}

impl<T> Entry<T> {
    fn matches(&self, key: &Key<'_>) -> bool {
        self.hash == key.hash
            && self.settings == key.settings
            && self.faces == key.faces
            && self.vertices.len() == key.vertices.len()
            && self
                .vertices
                .iter()
                .zip(key.vertices)
                .all(|(a, b)| *a == bits(*b))
    }
}

/// Values of type `T` built from a mesh (`vertices` [V] metres, `faces` [F]) and settings
/// (their `f32::to_bits` or integers), the `capacity` most recently used kept.
pub struct MeshMemo<T> {
    entries: Mutex<VecDeque<Entry<T>>>,
    capacity: usize,
}

impl<T> MeshMemo<T> {
    /// An empty memo keeping at most `capacity` values (usable in a `static`).
    pub const fn new(capacity: usize) -> Self {
        MeshMemo {
            entries: Mutex::new(VecDeque::new()),
            capacity,
        }
    }

    /// The value remembered for exactly this mesh and these settings, else `build()`,
    /// remembered. Errors of `build` are returned, not remembered.
    pub fn get_or_build<E>(
        &self,
        vertices: &[Vec3],
        faces: &[[u32; 3]],
        settings: &[u32],
        build: impl FnOnce() -> Result<T, E>,
    ) -> Result<Arc<T>, E> {
        let key = Key::new(vertices, faces, settings);
        {
            let mut entries = self.entries.lock().unwrap_or_else(|e| e.into_inner());
            if let Some(i) = entries.iter().position(|e| e.matches(&key)) {
                let entry = entries.remove(i).expect("found above");
                let value = entry.value.clone();
                entries.push_front(entry);
                return Ok(value);
            }
        }
        let value = Arc::new(build()?);
        let mut entries = self.entries.lock().unwrap_or_else(|e| e.into_inner());
        entries.push_front(Entry {
            hash: key.hash,
            settings: settings.to_vec(),
            vertices: vertices.iter().map(|&v| bits(v)).collect(),
            faces: faces.to_vec(),
            value: value.clone(),
        });
        entries.truncate(self.capacity);
        Ok(value)
    }

    /// The value remembered for exactly this mesh and these settings, without building one.
    pub fn remembered(
        &self,
        vertices: &[Vec3],
        faces: &[[u32; 3]],
        settings: &[u32],
    ) -> Option<Arc<T>> {
        let key = Key::new(vertices, faces, settings);
        let entries = self.entries.lock().unwrap_or_else(|e| e.into_inner());
        entries
            .iter()
            .find(|e| e.matches(&key))
            .map(|e| e.value.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn remembers_by_exact_bits_and_forgets_the_least_recently_used() {
        static MEMO: MeshMemo<usize> = MeshMemo::new(2);
        let v = vec![Vec3::ZERO, Vec3::X, Vec3::Y];
        let f = vec![[0, 1, 2]];
        let mut builds = 0;
        let mut get = |v: &[Vec3], s: &[u32]| {
            *MEMO
                .get_or_build(v, &f, s, || {
                    builds += 1;
                    Ok::<_, ()>(builds)
                })
                .unwrap()
        };
        assert_eq!(get(&v, &[1]), 1);
        assert_eq!(get(&v, &[1]), 1, "the same mesh and settings: remembered");
        assert_eq!(get(&v, &[2]), 2, "other settings: built");
        let mut moved = v.clone();
        moved[2].y += 1e-7;
        assert_eq!(get(&moved, &[1]), 3, "a vertex one ulp away: built");
        // Capacity 2: the first entry was the least recently used and is gone.
        assert!(MEMO.remembered(&v, &f, &[1]).is_none());
        assert_eq!(MEMO.remembered(&v, &f, &[2]).as_deref(), Some(&2));
        assert_eq!(MEMO.remembered(&moved, &f, &[1]).as_deref(), Some(&3));
        // Errors are returned, not remembered.
        let err = MEMO.get_or_build(&v, &f, &[9], || Err::<usize, _>("bad"));
        assert_eq!(err.unwrap_err(), "bad");
        assert!(MEMO.remembered(&v, &f, &[9]).is_none());
    }
}
