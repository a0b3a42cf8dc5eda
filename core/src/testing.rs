//! Test helpers shared by the unit tests (compiled for tests only): the
//! parsers' error and mutation helpers, a scene from XML, a small stack.

use crate::error::SceneError;
use crate::mesh::Mesh;
use proptest::prelude::*;

/// Asserts that `result` is a scene error at `file:line:column` whose message
/// contains `msg`.
pub fn assert_error_at<T: std::fmt::Debug>(
    result: Result<T, SceneError>,
    file: &str,
    line: u32,
    column: u32,
    msg: &str,
) {
    match result {
        Ok(v) => panic!("expected an error at {file}:{line}:{column}, got {v:?}"),
        Err(e) => {
            assert_eq!(
                (e.location.file.as_str(), e.location.line, e.location.column),
                (file, line, column),
                "wrong location: {e}"
            );
            assert!(
                e.message.contains(msg),
                "message {:?} lacks {msg:?}",
                e.message
            );
        }
    }
}

/// The invariants every loaded mesh satisfies.
pub fn check_mesh_invariants(m: &Mesh) {
    assert!(!m.triangles.is_empty());
    assert!(m.normals.is_empty() || m.normals.len() == m.positions.len());
    assert!(m.uvs.is_empty() || m.uvs.len() == m.positions.len());
    assert!(m.uvs.iter().all(|uv| uv.is_finite()));
    for t in &m.triangles {
        for &i in t {
            assert!((i as usize) < m.positions.len());
        }
    }
    for p in m.positions.iter().chain(&m.normals) {
        assert!(p.is_finite());
    }
}

/// One mutation of an input file.
#[derive(Debug, Clone)]
pub enum Edit {
    Flip(usize, u8),
    Insert(usize, u8),
    Delete(usize),
}

/// Random edits; inserted bytes favour `grammar`, the bytes that matter to
/// the format being mutated.
pub fn edit(grammar: &'static [u8]) -> impl Strategy<Value = Edit> {
    let byte = prop_oneof![prop::sample::select(grammar.to_vec()), any::<u8>()];
    prop_oneof![
        (any::<usize>(), any::<u8>()).prop_map(|(i, b)| Edit::Flip(i, b)),
        (any::<usize>(), byte).prop_map(|(i, b)| Edit::Insert(i, b)),
        any::<usize>().prop_map(Edit::Delete),
    ]
}

/// Applies `edits` in order (positions wrap around the current length).
pub fn apply_edits(mut bytes: Vec<u8>, edits: &[Edit]) -> Vec<u8> {
    for e in edits {
        match *e {
            Edit::Flip(i, b) if !bytes.is_empty() => {
                let i = i % bytes.len();
                bytes[i] ^= b;
            }
            Edit::Insert(i, b) => {
                let i = i % (bytes.len() + 1);
                bytes.insert(i, b);
            }
            Edit::Delete(i) if !bytes.is_empty() => {
                let i = i % bytes.len();
                bytes.remove(i);
            }
            _ => {}
        }
    }
    bytes
}

/// The scene of the single-file bundle `s.xml` = `xml` (panics if it does
/// not load: the tests' scenes are valid).
pub fn scene(xml: &str) -> crate::Scene {
    crate::Scene::from_bundle(&crate::Bundle {
        scene: "s.xml".into(),
        files: [("s.xml".to_string(), xml.as_bytes().to_vec())].into(),
    })
    .unwrap()
}

/// Runs `f` on a thread with a 256 KiB stack: what a recursion as deep as
/// the scene allows would overflow (and abort the process).
pub fn on_a_small_stack<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
    std::thread::Builder::new()
        .stack_size(256 << 10)
        .spawn(f)
        .unwrap()
        .join()
        .unwrap()
}
