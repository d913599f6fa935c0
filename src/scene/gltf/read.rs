//! Reading a glTF file and what it names, through the scene's
//! [`FileAccess`]: the JSON or GLB, its buffers and the images its
//! materials read, with URIs resolved here ([`locate`]) instead of by the `gltf`
//! crate, and the memory of meshes and images declared before it is
//! allocated.

use super::*;

/// The buffers and images of a glTF file, as [`import`] gives them: the
/// document, each buffer's bytes (padded to a multiple of four, as the
/// `gltf` crate's readers expect), and each image decoded when a material
/// reads it (`None` otherwise).
pub(super) type Imported = (
    gltf::Document,
    Vec<gltf::buffer::Data>,
    Vec<Option<gltf::image::Data>>,
);

/// Reads a glTF or GLB file once, through `access`, checking what the
/// `gltf` crate would trust before it does: the GLB lengths
/// ([`check_glb_lengths`]) and the accessor indices
/// ([`check_attribute_indices`]). Then validates it, checks its node graph
/// ([`check_instancing`]) and every file its buffers and images name,
/// declares the memory of its meshes and buffers, and reads its buffers
/// and the images its materials read (each declared from its header
/// before it is decoded).
pub(super) fn import(path: &Path, access: &FileAccess) -> Result<Imported, SceneError> {
    let err = |msg: String| SceneError::new(path, 0, msg);
    let bytes = access
        .read(path, FileKind::Scene)
        .map_err(|e| err(e.to_string()))?;
    check_glb_lengths(path, &bytes)?;
    let cannot = |e: gltf::Error| err(format!("cannot read glTF file: {e}"));
    let gltf::Gltf { document, mut blob } =
        gltf::Gltf::from_slice_without_validation(&bytes).map_err(cannot)?;
    check_attribute_indices(path, document.as_json())?;
    let document = gltf::Document::from_json(document.into_json()).map_err(cannot)?;
    // the JSON text, to name the line of a URI in errors (a GLB's is binary
    // around it: its errors have no line, and its bytes go now, the binary
    // chunk having been copied into `blob`)
    let text = if bytes.starts_with(b"glTF") {
        drop(bytes);
        Vec::new()
    } else {
        bytes
    };
    let fail = |what: String, uri: &str, e: String| {
        SceneError::new(
            path,
            uri_line(&text, uri),
            format!("{what} (`{}`): {e}", short_uri(uri)),
        )
    };

    // the node graph, and the memory of the meshes it instances
    if let Some(gscene) = document
        .default_scene()
        .or_else(|| document.scenes().next())
    {
        check_instancing(&document, &gscene, path)?;
        reserve_meshes(&document, &gscene, path, access)?;
    }

    // where each buffer and image comes from: every file checked before
    // any is read
    let base = path.parent().unwrap_or(Path::new("./"));
    let json = document.as_json();
    let mut buffer_src = Vec::with_capacity(json.buffers.len());
    for (i, b) in json.buffers.iter().enumerate() {
        buffer_src.push(match &b.uri {
            None => None,
            Some(uri) => Some(
                locate(uri, base, FileKind::Mesh, access)
                    .map_err(|e| fail(format!("buffer {i}"), uri, e))?,
            ),
        });
    }
    let mut image_src = Vec::with_capacity(json.images.len());
    for (i, img) in json.images.iter().enumerate() {
        // a bufferView comes first, as in the gltf crate
        image_src.push(match (&img.uri, &img.buffer_view) {
            (Some(uri), None) => Some(
                locate(uri, base, FileKind::Image, access)
                    .map_err(|e| fail(format!("image {i}"), uri, e))?,
            ),
            _ => None,
        });
    }

    // the buffers
    let mut buffers = Vec::with_capacity(json.buffers.len());
    for (i, (b, src)) in json.buffers.iter().zip(buffer_src).enumerate() {
        let uri = b.uri.as_deref().unwrap_or("");
        let what = || match &b.uri {
            Some(_) => format!("buffer {i}"),
            None => format!("buffer {i} (the GLB's binary chunk)"),
        };
        let size = match &src {
            None => blob.as_ref().map_or(0, |d| d.len() as u64),
            Some(Located::Data(d, _)) => d.len() as u64,
            Some(Located::File(_, size)) => *size,
        };
        access
            .reserve(format!("glTF buffer {i} `{}`", short_uri(uri)), size)
            .map_err(|e| fail(what(), uri, e.to_string()))?;
        let mut data = match src {
            None => blob.take().ok_or_else(|| {
                err(format!(
                    "buffer {i} has no uri, so it is the GLB's binary chunk, \
                     but the file has none (or another buffer took it)"
                ))
            })?,
            Some(Located::Data(d, _)) => d,
            Some(Located::File(p, _)) => access
                .read(&p, FileKind::Mesh)
                .map_err(|e| fail(what(), uri, e.to_string()))?,
        };
        let declared = b.byte_length.0;
        if (data.len() as u64) < declared {
            return Err(fail(
                what(),
                uri,
                format!(
                    "it has {} bytes, fewer than its byteLength {declared}",
                    data.len()
                ),
            ));
        }
        while data.len() % 4 != 0 {
            data.push(0);
        }
        buffers.push(gltf::buffer::Data(data));
    }

    let images = read_images(path, &text, &document, &buffers, image_src, access)?;
    Ok((document, buffers, images))
}

/// The images of `document` a material reads (as its base colour, its
/// metallic–roughness, its emission or its normals; None for the others),
/// each read from where `image_src` says ([`locate`]d by [`import`]) or
/// from its buffer view, and declared to `access` from its header before
/// it is decoded. `text` is the glTF's JSON text, to name a URI's line.
pub(super) fn read_images(
    path: &Path,
    text: &[u8],
    document: &gltf::Document,
    buffers: &[gltf::buffer::Data],
    image_src: Vec<Option<Located>>,
    access: &FileAccess,
) -> Result<Vec<Option<gltf::image::Data>>, SceneError> {
    let err = |msg: String| SceneError::new(path, 0, msg);
    let fail = |what: String, uri: &str, e: String| {
        SceneError::new(
            path,
            uri_line(text, uri),
            format!("{what} (`{}`): {e}", short_uri(uri)),
        )
    };
    let json = document.as_json();
    // the images the materials read, each declared from its header
    // before it is decoded
    let mut used = vec![false; json.images.len()];
    for m in document.materials() {
        let pbr = m.pbr_metallic_roughness();
        let sources = [
            pbr.base_color_texture().map(|i| i.texture()),
            pbr.metallic_roughness_texture().map(|i| i.texture()),
            m.emissive_texture().map(|i| i.texture()),
            m.normal_texture().map(|i| i.texture()),
        ];
        for t in sources.into_iter().flatten() {
            if let Some(u) = used.get_mut(t.source().index()) {
                *u = true;
            }
        }
    }
    let mut images = Vec::with_capacity(json.images.len());
    for (i, (img, src)) in json.images.iter().zip(image_src).enumerate() {
        if !used[i] {
            images.push(None);
            continue;
        }
        let uri = match img.buffer_view {
            None => img.uri.as_deref().unwrap_or(""),
            Some(_) => "",
        };
        let mime = img.mime_type.as_ref().map(|m| m.0.as_str());
        // a data: URI's own media type comes first, as in the gltf crate
        let (bytes, mime): (std::borrow::Cow<[u8]>, Option<&str>) = match &src {
            Some(Located::File(p, _)) => (
                access
                    .read(p, FileKind::Image)
                    .map_err(|e| fail(format!("image {i}"), uri, e.to_string()))?
                    .into(),
                mime,
            ),
            Some(Located::Data(d, data_mime)) => (d[..].into(), data_mime.as_deref().or(mime)),
            None => match img
                .buffer_view
                .as_ref()
                .and_then(|v| view_bytes(document, buffers, v.value()))
            {
                Some(b) => (b.into(), mime),
                None => {
                    return Err(err(format!(
                        "image {i} has no uri, and no bufferView within its buffer"
                    )))
                }
            },
        };
        let name = if uri.is_empty() {
            format!("bufferView {}", img.buffer_view.map_or(0, |v| v.value()))
        } else {
            short_uri(uri)
        };
        let image = decode_image(&bytes, mime, uri, &name, access)
            .map_err(|e| fail(format!("image {i}"), uri, e))?;
        images.push(image);
    }
    Ok(images)
}

/// Where a glTF URI points: bytes it holds (a `data:` URI, with its media
/// type), or a file, checked by the access, with its size.
#[derive(Debug)]
pub(crate) enum Located {
    /// The decoded bytes of a `data:` URI, and its media type if it gives
    /// one.
    Data(Vec<u8>, Option<String>),
    /// A file the access allows, and its size.
    File(PathBuf, u64),
}

/// Resolves the URI `uri` of a glTF file whose folder is `base`: a `data:`
/// URI is decoded (base64, or percent-encoded); a relative path is
/// percent-decoded and joined to `base`; a `file:` URI names a path (an
/// absolute one, usually). Other schemes are refused. A path is then
/// checked by `access` as a file of `kind` (under an allowed folder, a
/// regular file, within the kind's size), but not read. The error says
/// why, naming the file.
pub(crate) fn locate(
    uri: &str,
    base: &Path,
    kind: FileKind,
    access: &FileAccess,
) -> Result<Located, String> {
    if let Some(rest) = uri.strip_prefix("data:") {
        let (header, payload) = rest
            .split_once(',')
            .ok_or("a data: URI needs a `,` before its data")?;
        let mime = header
            .split(';')
            .next()
            .filter(|m| !m.is_empty())
            .map(str::to_string);
        let bytes = if header.ends_with(";base64") {
            base64_decode(payload)?
        } else {
            percent_decode(payload)
        };
        return Ok(Located::Data(bytes, mime));
    }
    let file = if let Some(rest) = uri.strip_prefix("file://").or(uri.strip_prefix("file:")) {
        rest
    } else if uri.contains(':') {
        return Err(
            "unsupported URI scheme: kalos reads relative paths, file: and data: URIs".into(),
        );
    } else {
        uri
    };
    let file = String::from_utf8(percent_decode(file))
        .map_err(|_| "the URI is not UTF-8 once percent-decoded".to_string())?;
    let p = base.join(file);
    let (_, size) = access.check(&p, kind).map_err(|e| e.to_string())?;
    Ok(Located::File(p, size))
}

/// The bytes of buffer view `view` (an image's), `None` when it does not
/// lie within its buffer.
pub(super) fn view_bytes<'b>(
    doc: &gltf::Document,
    buffers: &'b [gltf::buffer::Data],
    view: usize,
) -> Option<&'b [u8]> {
    let view = doc.views().nth(view)?;
    let data = buffers.get(view.buffer().index())?;
    let end = view.offset().checked_add(view.length())?;
    data.0.get(view.offset()..end)
}

/// Decodes an image (PNG or JPEG, by its media type, its file
/// extension, else its first bytes), after declaring its pixels' memory to
/// `access` from its header (named `name`). `None` when it decodes to a
/// pixel format the loader does not convert (then a warning says so).
pub(super) fn decode_image(
    bytes: &[u8],
    mime: Option<&str>,
    uri: &str,
    name: &str,
    access: &FileAccess,
) -> Result<Option<gltf::image::Data>, String> {
    use image::{DynamicImage as D, ImageDecoder, ImageFormat};
    let ext = match uri.rsplit_once('.') {
        Some((_, ext)) if !uri.starts_with("data:") => ext.to_ascii_lowercase(),
        _ => String::new(),
    };
    let format = match (mime, ext.as_str()) {
        (Some("image/png"), _) => Some(ImageFormat::Png),
        (Some("image/jpeg"), _) => Some(ImageFormat::Jpeg),
        (None, "png") => Some(ImageFormat::Png),
        (None, "jpg" | "jpeg") => Some(ImageFormat::Jpeg),
        _ => None,
    };
    let format = format
        .or_else(|| {
            image::guess_format(bytes)
                .ok()
                .filter(|f| matches!(f, ImageFormat::Png | ImageFormat::Jpeg))
        })
        .ok_or_else(|| {
            format!(
                "unsupported image encoding{}: glTF images are PNG or JPEG",
                mime.map_or(String::new(), |m| format!(" `{m}`"))
            )
        })?;
    let cannot = |e: image::ImageError| format!("cannot decode the image: {e}");
    let decoder = image::ImageReader::with_format(std::io::Cursor::new(bytes), format)
        .into_decoder()
        .map_err(cannot)?;
    let (w, h) = decoder.dimensions();
    let bpp = decoder.color_type().bytes_per_pixel() as u64;
    drop(decoder);
    // the decoded pixels, and the linear texture made from them
    let texel = bpp + std::mem::size_of::<Rgb>() as u64;
    access
        .reserve(
            format!("glTF image `{name}` ({w}×{h})"),
            (w as u64 * h as u64).saturating_mul(texel),
        )
        .map_err(|e| e.to_string())?;
    let img = image::load_from_memory_with_format(bytes, format).map_err(cannot)?;
    // as the gltf crate's image::Data::new
    let format = match img {
        D::ImageLuma8(_) => gltf::image::Format::R8,
        D::ImageLumaA8(_) => gltf::image::Format::R8G8,
        D::ImageRgb8(_) => gltf::image::Format::R8G8B8,
        D::ImageRgba8(_) => gltf::image::Format::R8G8B8A8,
        D::ImageLuma16(_) => gltf::image::Format::R16,
        D::ImageLumaA16(_) => gltf::image::Format::R16G16,
        D::ImageRgb16(_) => gltf::image::Format::R16G16B16,
        D::ImageRgba16(_) => gltf::image::Format::R16G16B16A16,
        D::ImageRgb32F(_) => gltf::image::Format::R32G32B32FLOAT,
        D::ImageRgba32F(_) => gltf::image::Format::R32G32B32A32FLOAT,
        _ => return Ok(None),
    };
    let (width, height) = (img.width(), img.height());
    Ok(Some(gltf::image::Data {
        pixels: img.into_bytes(),
        format,
        width,
        height,
    }))
}

/// Declares the memory of the meshes the default scene instances: each
/// mesh's triangles and vertices (from its accessors' counts) times the
/// paths to it through the node graph (a DAG: [`check_instancing`] has
/// refused cycles).
pub(super) fn reserve_meshes(
    doc: &gltf::Document,
    gscene: &gltf::Scene,
    path: &Path,
    access: &FileAccess,
) -> Result<(), SceneError> {
    let instances = node_instances(doc, gscene);
    let mut of_mesh = vec![0u64; doc.meshes().len()];
    for node in doc.nodes() {
        if let Some(m) = node.mesh() {
            of_mesh[m.index()] = of_mesh[m.index()].saturating_add(instances[node.index()]);
        }
    }
    for mesh in doc.meshes() {
        let k = of_mesh[mesh.index()];
        if k == 0 {
            continue;
        }
        let (mut vertices, mut triangles, mut tangents) = (0u64, 0u64, 0u64);
        for p in mesh
            .primitives()
            .filter(|p| p.mode() == gltf::mesh::Mode::Triangles)
        {
            let n = p.get(&gltf::Semantic::Positions).map_or(0, |a| a.count()) as u64;
            vertices += n;
            let t = p.indices().map_or(n, |a| a.count() as u64) / 3;
            triangles += t;
            if p.material().normal_texture().is_some() {
                // a normal map's corner tangents, in object and in world
                // space, and the TANGENT attribute read
                tangents = tangents.saturating_add(t.saturating_mul(96).saturating_add(n * 16));
            }
        }
        let item = format!(
            "glTF mesh {} `{}` ({triangles} triangles × {k} instances)",
            mesh.index(),
            mesh.name().unwrap_or("")
        );
        access
            .reserve(
                item,
                crate::scene::mesh_memory(vertices, triangles)
                    .saturating_add(tangents)
                    .saturating_mul(k),
            )
            .map_err(|e| SceneError::new(path, 0, e.to_string()))?;
    }
    Ok(())
}

/// How many times the walk of `gscene` reaches each node: the number of
/// paths to it from the scene's roots (saturating). The node graph must
/// be acyclic.
pub(super) fn node_instances(doc: &gltf::Document, gscene: &gltf::Scene) -> Vec<u64> {
    let nodes: Vec<gltf::Node> = doc.nodes().collect();
    // a post-order of the nodes reachable from the roots: each after its
    // descendants
    let mut seen = vec![false; nodes.len()];
    let mut post = Vec::with_capacity(nodes.len());
    for root in gscene.nodes() {
        let mut stack = vec![(root.index(), false)];
        while let Some((i, done)) = stack.pop() {
            if done {
                post.push(i);
                continue;
            }
            if std::mem::replace(&mut seen[i], true) {
                continue;
            }
            stack.push((i, true));
            stack.extend(
                nodes[i]
                    .children()
                    .map(|c| (c.index(), false))
                    .filter(|&(c, _)| !seen[c]),
            );
        }
    }
    let mut count = vec![0u64; nodes.len()];
    for root in gscene.nodes() {
        count[root.index()] = count[root.index()].saturating_add(1);
    }
    // parents before children
    for &i in post.iter().rev() {
        for c in nodes[i].children() {
            count[c.index()] = count[c.index()].saturating_add(count[i]);
        }
    }
    count
}

/// A URI as errors show it: a long `data:` URI cut short.
pub(super) fn short_uri(uri: &str) -> String {
    match uri.char_indices().nth(60) {
        Some((at, _)) => format!("{}…", &uri[..at]),
        None => uri.to_string(),
    }
}

/// The 1-based line of `text` (a glTF's JSON) that holds the string `uri`,
/// 0 when it is not found as written (escaped, or a GLB).
pub(super) fn uri_line(text: &[u8], uri: &str) -> u32 {
    if text.is_empty() || uri.is_empty() || uri.len() > 4096 {
        return 0;
    }
    let quoted = format!("\"{uri}\"");
    text.windows(quoted.len())
        .position(|w| w == quoted.as_bytes())
        .map_or(0, |at| {
            1 + text[..at].iter().filter(|&&b| b == b'\n').count() as u32
        })
}

/// `%XX` escapes decoded (others kept as written).
pub(super) fn percent_decode(s: &str) -> Vec<u8> {
    let b = s.as_bytes();
    let hex = |c: u8| (c as char).to_digit(16).map(|d| d as u8);
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' && i + 2 < b.len() {
            if let (Some(h), Some(l)) = (hex(b[i + 1]), hex(b[i + 2])) {
                out.push(h << 4 | l);
                i += 3;
                continue;
            }
        }
        out.push(b[i]);
        i += 1;
    }
    out
}

/// Decodes base64 (the standard or the URL-safe alphabet; padding
/// optional), as `data:` URIs hold it.
pub(super) fn base64_decode(s: &str) -> Result<Vec<u8>, String> {
    let s = s.trim_end_matches('=');
    if s.len() % 4 == 1 {
        return Err("its base64 data is truncated".into());
    }
    let mut out = Vec::with_capacity(s.len() / 4 * 3 + 2);
    let (mut acc, mut bits) = (0u32, 0u32);
    for (k, c) in s.bytes().enumerate() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            _ => {
                return Err(format!(
                    "character {k} of its base64 data, {:?}, is not a base64 digit",
                    c as char
                ))
            }
        };
        acc = (acc << 6) | v as u32;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod uri_tests {
    use super::*;

    #[test]
    fn base64_decodes_with_and_without_padding_and_refuses_other_characters(
    ) -> Result<(), Box<dyn std::error::Error>> {
        assert_eq!(base64_decode("aGVsbG8=")?, b"hello");
        assert_eq!(base64_decode("aGVsbG8")?, b"hello");
        assert_eq!(base64_decode("aGVsbG8h")?, b"hello!");
        assert_eq!(base64_decode("")?, b"");
        assert_eq!(base64_decode("_-8=")?, [0xff, 0xef]);
        assert!(base64_decode("aGV*")
            .err()
            .ok_or("expected an error")?
            .contains("not a base64 digit"));
        assert!(base64_decode("aGVsb")
            .err()
            .ok_or("expected an error")?
            .contains("truncated"));
        Ok(())
    }

    #[test]
    fn percent_escapes_are_decoded_and_others_kept() -> Result<(), Box<dyn std::error::Error>> {
        assert_eq!(percent_decode("my%20tex%2Epng"), b"my tex.png");
        assert_eq!(percent_decode("100%"), b"100%");
        assert_eq!(percent_decode("a%zzb%4"), b"a%zzb%4");
        Ok(())
    }

    #[test]
    fn the_line_of_a_uri_is_found_in_the_json() -> Result<(), Box<dyn std::error::Error>> {
        let text = b"{\n\"buffers\":[\n{\"uri\":\"a.bin\"}]}";
        assert_eq!(uri_line(text, "a.bin"), 3);
        assert_eq!(uri_line(text, "b.bin"), 0);
        assert_eq!(uri_line(b"", "a.bin"), 0);
        Ok(())
    }

    #[test]
    fn data_uris_are_decoded_and_other_schemes_refused() -> Result<(), Box<dyn std::error::Error>> {
        let a = FileAccess::nothing();
        let base = Path::new(".");
        match locate("data:text/plain;base64,aGk=", base, FileKind::Mesh, &a) {
            Ok(Located::Data(d, mime)) => {
                assert_eq!(d, b"hi");
                assert_eq!(mime.as_deref(), Some("text/plain"));
            }
            r => panic!("{r:?}"),
        }
        match locate("data:,a%20b", base, FileKind::Mesh, &a) {
            Ok(Located::Data(d, None)) => assert_eq!(d, b"a b"),
            r => panic!("{r:?}"),
        }
        let e = locate("https://example.com/a.bin", base, FileKind::Mesh, &a)
            .err()
            .ok_or("expected an error")?;
        assert!(e.contains("unsupported URI scheme"), "{e}");
        // a path is checked by the access, which here allows nothing
        let e = locate("Cargo.toml", base, FileKind::Mesh, &a)
            .err()
            .ok_or("expected an error")?;
        assert!(e.contains("--allow-read"), "{e}");
        Ok(())
    }
}
