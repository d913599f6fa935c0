//! Checks of what the `gltf` crate would trust before it does: GLB
//! lengths, accessor indices and types, and the node graph's instancing.

use super::*;

/// Checks that every mesh primitive's attributes name an accessor that
/// exists, before the `gltf` crate validates the file: its validation of a
/// primitive indexes the accessor list with the POSITION index unchecked
/// (gltf-json 1.4.1), so a bad index panicked instead of erroring.
pub(super) fn check_attribute_indices(
    path: &Path,
    root: &gltf::json::Root,
) -> Result<(), SceneError> {
    let err = |msg: String| SceneError::new(path, 0, msg);
    let n = root.accessors.len();
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (k, prim) in mesh.primitives.iter().enumerate() {
            let named = prim.attributes.values().chain(prim.indices.as_ref());
            if let Some(bad) = named.map(|i| i.value()).find(|&i| i >= n) {
                return Err(err(format!(
                    "mesh {m} primitive {k} names accessor {bad}, but the file has {n}"
                )));
            }
        }
    }
    Ok(())
}

/// Checks the component types of the accessors kalos reads, which the
/// `gltf` crate's readers assume valid (an index accessor of floats reached
/// an `unreachable!`).
pub(super) fn check_accessor_types(prim: &gltf::Primitive) -> Result<(), String> {
    use gltf::accessor::{DataType as T, Dimensions as D};
    use gltf::Semantic as S;
    let ok = |a: &gltf::Accessor, types: &[T], dims: D| {
        types.contains(&a.data_type()) && a.dimensions() == dims
    };
    if let Some(a) = prim.indices() {
        if !ok(&a, &[T::U8, T::U16, T::U32], D::Scalar) {
            return Err(format!(
                "the indices must be unsigned integer scalars, found {:?} {:?}",
                a.data_type(),
                a.dimensions()
            ));
        }
    }
    for (semantic, a) in prim.attributes() {
        let good = match semantic {
            S::Positions | S::Normals => ok(&a, &[T::F32], D::Vec3),
            S::TexCoords(_) => ok(&a, &[T::U8, T::U16, T::F32], D::Vec2),
            _ => true,
        };
        if !good {
            return Err(format!(
                "attribute {semantic:?} has the wrong type ({:?} {:?})",
                a.data_type(),
                a.dimensions()
            ));
        }
    }
    Ok(())
}

/// Checks a binary glTF's header and chunk lengths against the file's size
/// before the `gltf` crate sizes a buffer from them (it trusts the header:
/// a claimed 4 GB aborted on the allocation). A file that does not start
/// with the GLB magic is left to the JSON parser.
pub(super) fn check_glb_lengths(path: &Path, bytes: &[u8]) -> Result<(), SceneError> {
    let err = |msg: String| SceneError::new(path, 0, msg);
    let size = bytes.len() as u64;
    if size < 12 || &bytes[..4] != b"glTF" {
        return Ok(());
    }
    let word = |i: u64| {
        let i = i as usize;
        u32::from_le_bytes([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]]) as u64
    };
    let claimed = word(8);
    // shorter than the header itself: the gltf crate subtracts 12 from it
    // unchecked (gltf 1.4.1), which debug builds panic on
    if claimed < 12 {
        return Err(err(format!(
            "GLB header claims {claimed} bytes, fewer than the 12 of the header itself: corrupt"
        )));
    }
    if claimed > size {
        return Err(err(format!(
            "GLB header claims {claimed} bytes, but the file has {size}: truncated or corrupt"
        )));
    }
    // Each chunk: length, type, then `length` bytes, all inside the claimed size
    let mut at = 12u64;
    let mut k = 0;
    while at + 8 <= claimed {
        let len = word(at);
        if at + 8 + len > claimed {
            return Err(err(format!(
                "GLB chunk {k} at byte {at} claims {len} bytes, but only {} remain of the {claimed} the header gives",
                claimed - at - 8
            )));
        }
        at += 8 + len;
        k += 1;
    }
    Ok(())
}

/// Refuses a node graph that is not a forest of finite size before any
/// mesh is instanced: a node that is its own ancestor (the walk would never
/// end), or a DAG whose shared nodes multiply into more than
/// [`crate::scene::MAX_TRIANGLES`] triangles or [`MAX_NODES`] node instances.
pub(super) fn check_instancing(
    doc: &gltf::Document,
    gscene: &gltf::Scene,
    path: &Path,
) -> Result<(), SceneError> {
    let err = |msg: String| SceneError::new(path, 0, msg);
    // Triangles of one instance of each mesh, from the accessor counts alone
    let mesh_tris: Vec<u64> = doc
        .meshes()
        .map(|m| {
            m.primitives()
                .filter(|p| p.mode() == gltf::mesh::Mode::Triangles)
                .map(|p| {
                    let n = match p.indices() {
                        Some(a) => a.count(),
                        None => p.get(&gltf::Semantic::Positions).map_or(0, |a| a.count()),
                    };
                    n as u64 / 3
                })
                .sum()
        })
        .collect();

    // Post-order walk with colours: grey nodes are on the current path, so
    // meeting one again is a cycle; black nodes carry their subtree totals
    // (triangles, node instances), summed with saturation
    let nodes: Vec<gltf::Node> = doc.nodes().collect();
    let mut total: Vec<Option<(u64, u64)>> = vec![None; nodes.len()];
    let mut grey = vec![false; nodes.len()];
    for root in gscene.nodes() {
        let mut stack = vec![(root.index(), false)];
        while let Some((i, expanded)) = stack.pop() {
            if expanded {
                let node = &nodes[i];
                let own = node.mesh().map_or(0, |m| mesh_tris[m.index()]);
                let (mut tris, mut count) = (own, 1u64);
                for c in node.children() {
                    let (t, n) = total[c.index()].unwrap_or((0, 0));
                    tris = tris.saturating_add(t);
                    count = count.saturating_add(n);
                }
                total[i] = Some((tris, count));
                grey[i] = false;
                continue;
            }
            if total[i].is_some() {
                continue;
            }
            grey[i] = true;
            stack.push((i, true));
            for c in nodes[i].children() {
                let j = c.index();
                if grey[j] {
                    let what = if j == i {
                        format!("glTF node {j} is its own child")
                    } else {
                        format!("glTF node {j} is its own ancestor (through node {i})")
                    };
                    return Err(err(format!(
                        "{what}: the node graph must be a tree (or a DAG), not a cycle"
                    )));
                }
                if total[j].is_none() {
                    stack.push((j, false));
                }
            }
        }
    }
    let (tris, count) = gscene
        .nodes()
        .filter_map(|n| total[n.index()])
        .fold((0u64, 0u64), |(t, c), (a, b)| {
            (t.saturating_add(a), c.saturating_add(b))
        });
    if tris > crate::scene::MAX_TRIANGLES {
        return Err(err(format!(
            "glTF scene instances {tris} triangles (shared nodes multiply their meshes); \
             kalos loads at most {}",
            crate::scene::MAX_TRIANGLES
        )));
    }
    if count > MAX_NODES {
        return Err(err(format!(
            "glTF scene instances {count} nodes (shared nodes multiply); kalos walks at most {MAX_NODES}"
        )));
    }
    Ok(())
}
