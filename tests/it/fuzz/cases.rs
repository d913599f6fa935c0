//! Mutated scene files for the loader fuzz test (`tests/it/fuzz.rs`) and
//! its long subprocess form (`examples/fuzz_loaders.rs`, which includes
//! this file by path). Standard library only, so both can share it.
//!
//! A *seed* is a small valid scene: a set of files and the one that is
//! loaded. A *case* is a seed with one of its files mutated 1–4 times by
//! operators that target what loaders trust: numbers (NaN, infinities,
//! huge counts, negatives), header lengths in binary files, lines repeated
//! or removed, and plain byte damage. A case is a pure function of its
//! index and the run's seed, so any failure can be replayed.

#![allow(dead_code)]

use std::path::Path;

/// The run seed of the CI test and of the example's default run.
pub const RUN_SEED: u64 = 1;

/// Particles of a density case: its default is millions whatever the
/// film size, and a case should cost milliseconds.
pub const DENSITY_PARTICLES: u64 = 20_000;

/// splitmix64: enough randomness for choosing mutations, and a pure
/// function of its state.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }
    pub fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Uniform in `0..n` (`n > 0`).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    pub fn pick<'a, T>(&mut self, xs: &'a [T]) -> &'a T {
        &xs[self.below(xs.len())]
    }
}

/// One file of a seed.
#[derive(Clone)]
pub struct File {
    pub name: String,
    pub bytes: Vec<u8>,
    /// Whether the mutators treat it as text (token and line operators)
    /// or as binary (word overwrites).
    pub text: bool,
}

/// A small valid scene.
#[derive(Clone)]
pub struct Seed {
    /// What it exercises, for the report.
    pub label: &'static str,
    /// The file given to the loader.
    pub main: String,
    /// The file the mutations damage.
    pub target: String,
    pub files: Vec<File>,
}

/// A mutated seed, ready to write.
pub struct Case {
    pub label: &'static str,
    pub main: String,
    pub files: Vec<File>,
    /// The operators applied, for the failure message.
    pub ops: Vec<String>,
}

impl Case {
    /// Writes every file into `dir`.
    pub fn write(&self, dir: &Path) -> std::io::Result<()> {
        for f in &self.files {
            std::fs::write(dir.join(&f.name), &f.bytes)?;
        }
        Ok(())
    }
}

fn text(name: &str, s: &str) -> File {
    File {
        name: name.into(),
        bytes: s.as_bytes().to_vec(),
        text: true,
    }
}

fn binary(name: &str, b: Vec<u8>) -> File {
    File {
        name: name.into(),
        bytes: b,
        text: false,
    }
}

fn seed(label: &'static str, main: &str, target: &str, files: Vec<File>) -> Seed {
    Seed {
        label,
        main: main.into(),
        target: target.into(),
        files,
    }
}

/// A unit cube as OBJ, with normals and texture coordinates.
const CUBE_OBJ: &str = "\
# cube
mtllib cube.mtl
o cube
v -1 -1 -1
v 1 -1 -1
v 1 1 -1
v -1 1 -1
v -1 -1 1
v 1 -1 1
v 1 1 1
v -1 1 1
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 -1
vn 0 0 1
usemtl white
f 1/1/1 3/3/1 2/2/1
f 1/1/1 4/4/1 3/3/1
f 5/1/2 6/2/2 7/3/2
f 5/1/2 7/3/2 8/4/2
f 1/1 2/2 6/3
f 1/1 6/3 5/4
usemtl lamp
f 4 8 7
f 4 7 3
f 1 5 8
f 1 8 4
f 2 3 7
f 2 7 6
";

const CUBE_MTL: &str = "\
newmtl white
Kd 0.8 0.8 0.8
newmtl lamp
Kd 0.5 0.5 0.5
Ke 4 4 4
";

/// The vertices and faces of a small mesh for the PLY and glTF seeds: a
/// square floor and a tilted emitting quad above it.
fn quad_mesh() -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let v = vec![
        [-1.0, 0.0, -1.0],
        [1.0, 0.0, -1.0],
        [1.0, 0.0, 1.0],
        [-1.0, 0.0, 1.0],
        [-0.3, 1.0, -0.3],
        [0.3, 1.1, -0.3],
        [0.3, 1.1, 0.3],
        [-0.3, 1.0, 0.3],
    ];
    let f = vec![[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]];
    (v, f)
}

fn ply_ascii() -> String {
    let (v, f) = quad_mesh();
    let mut s = format!(
        "ply\nformat ascii 1.0\ncomment kalos fuzz seed\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property float u\nproperty float v\n\
         element face {}\nproperty list uchar int vertex_indices\nend_header\n",
        v.len(),
        f.len()
    );
    for p in &v {
        s += &format!("{} {} {} 0 1 0 {} {}\n", p[0], p[1], p[2], p[0], p[2]);
    }
    for t in &f {
        s += &format!("3 {} {} {}\n", t[0], t[1], t[2]);
    }
    s
}

fn ply_binary() -> Vec<u8> {
    let (v, f) = quad_mesh();
    let mut b = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         element face {}\nproperty list uchar uint vertex_indices\nend_header\n",
        v.len(),
        f.len()
    )
    .into_bytes();
    for p in &v {
        for c in p {
            b.extend_from_slice(&c.to_le_bytes());
        }
    }
    for t in &f {
        b.push(3);
        for i in t {
            b.extend_from_slice(&i.to_le_bytes());
        }
    }
    b
}

/// The mesh's vertex and index bytes, as one glTF buffer.
fn gltf_buffer() -> (Vec<u8>, usize, usize, usize) {
    let (v, f) = quad_mesh();
    let mut b = Vec::new();
    for p in &v {
        for c in p {
            b.extend_from_slice(&c.to_le_bytes());
        }
    }
    let pos_len = b.len();
    for t in &f {
        for i in t {
            b.extend_from_slice(&(*i as u16).to_le_bytes());
        }
    }
    let idx_len = b.len() - pos_len;
    (b, pos_len, idx_len, v.len())
}

fn gltf_json(uri: Option<&str>) -> String {
    let (buf, pos_len, idx_len, nv) = gltf_buffer();
    let uri = match uri {
        Some(u) => format!(",\"uri\":\"{u}\""),
        None => String::new(),
    };
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0,1]}}],
"nodes":[{{"mesh":0,"children":[1]}},{{"mesh":0,"translation":[0,0.2,0],"scale":[0.5,0.5,0.5]}}],
"materials":[{{"pbrMetallicRoughness":{{"baseColorFactor":[0.8,0.7,0.6,1],"metallicFactor":0,"roughnessFactor":0.6}},"emissiveFactor":[1,1,1],"extensions":{{"KHR_materials_emissive_strength":{{"emissiveStrength":2}}}}}}],
"extensionsUsed":["KHR_materials_emissive_strength"],
"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1,"material":0}}]}}],
"accessors":[{{"bufferView":0,"componentType":5126,"count":{nv},"type":"VEC3","min":[-1,0,-1],"max":[1,1.1,1]}},
{{"bufferView":1,"componentType":5123,"count":{ni},"type":"SCALAR"}}],
"bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":{pos_len}}},{{"buffer":0,"byteOffset":{pos_len},"byteLength":{idx_len}}}],
"buffers":[{{"byteLength":{len}{uri}}}]}}"#,
        ni = idx_len / 2,
        len = buf.len(),
    )
}

fn glb() -> Vec<u8> {
    let (mut buf, ..) = gltf_buffer();
    let mut json = gltf_json(None).into_bytes();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    while !buf.len().is_multiple_of(4) {
        buf.push(0);
    }
    let total = 12 + 8 + json.len() + 8 + buf.len();
    let mut b = Vec::new();
    for w in [
        0x4654_6C67u32,
        2,
        total as u32,
        json.len() as u32,
        0x4E4F_534A,
    ] {
        b.extend_from_slice(&w.to_le_bytes());
    }
    b.extend_from_slice(&json);
    for w in [buf.len() as u32, 0x004E_4942] {
        b.extend_from_slice(&w.to_le_bytes());
    }
    b.extend_from_slice(&buf);
    b
}

/// A Mitsuba scene touching most of what the XML loader reads: defaults,
/// an include, transforms, every shape kind, textured and layered BSDFs,
/// and every emitter kind.
const SCENE_XML: &str = r#"<scene version="3.0.0">
    <default name="spp" value="4"/>
    <default name="w" value="16"/>
    <integrator type="path"><integer name="max_depth" value="4"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <transform name="to_world"><lookat origin="0, 2, 6" target="0, 0.5, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm"><integer name="width" value="$w"/><integer name="height" value="12"/></film>
    </sensor>
    <include filename="materials.xml"/>
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="-90"/><scale value="4"/></transform>
        <ref id="floor"/>
    </shape>
    <shape type="cube">
        <transform name="to_world"><scale x="0.3" y="0.5" z="0.3"/><translate x="-1" y="0.5"/></transform>
        <bsdf type="roughconductor"><string name="material" value="Au"/><float name="alpha" value="0.2"/></bsdf>
    </shape>
    <shape type="sphere">
        <point name="center" x="1" y="0.5" z="0"/><float name="radius" value="0.5"/>
        <bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf>
    </shape>
    <shape type="disk">
        <transform name="to_world"><rotate x="1" angle="90"/><translate y="3"/></transform>
        <emitter type="area"><rgb name="radiance" value="5, 5, 4"/></emitter>
    </shape>
    <shape type="obj">
        <string name="filename" value="cube.obj"/>
        <transform name="to_world"><scale value="0.2"/><translate x="0" y="0.2" z="1"/></transform>
        <bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.2, 0.4, 0.6"/></bsdf>
    </shape>
    <shape type="ply">
        <string name="filename" value="quad.ply"/>
        <transform name="to_world"><translate z="-1.5"/></transform>
        <ref id="floor"/>
    </shape>
    <shape type="sphere">
        <point name="center" x="0" y="2" z="2"/><float name="radius" value="0.1"/>
        <emitter type="area"><rgb name="radiance" value="20, 20, 20"/></emitter>
    </shape>
    <emitter type="constant"><rgb name="radiance" value="0.05"/></emitter>
</scene>
"#;

const MATERIALS_XML: &str = r#"<scene version="3.0.0">
    <bsdf type="twosided" id="floor">
        <bsdf type="diffuse">
            <texture type="checkerboard" name="reflectance">
                <rgb name="color0" value="0.2"/><rgb name="color1" value="0.8"/>
                <transform name="to_uv"><scale x="4" y="4"/></transform>
            </texture>
        </bsdf>
    </bsdf>
    <bsdf type="roughplastic" id="unused">
        <float name="alpha" value="0.3"/><string name="distribution" value="ggx"/>
    </bsdf>
</scene>
"#;

/// The seeds: one per loader and file form, plus the XML scene with its
/// mesh files and include mutated in turn.
/// A pbrt-v4 scene with an Include, transforms, attributes, an object
/// instance, every shape kind, textured and stand-in materials, an area
/// and an environment light.
const SCENE_PBRT: &str = r#"# fuzz seed
LookAt 0 1 -4  0 0.5 0  0 1 0
Camera "perspective" "float fov" [40]
Film "rgb" "integer xresolution" [16] "integer yresolution" [12]
Sampler "independent" "integer pixelsamples" [2]
WorldBegin
LightSource "infinite" "rgb L" [0.2 0.2 0.3]
Include "materials.pbrt"
AttributeBegin
    Translate 0 2 0
    AreaLightSource "diffuse" "blackbody L" [4000] "float scale" [5]
    Shape "disk" "float radius" [0.5]
AttributeEnd
AttributeBegin
    NamedMaterial "checks"
    Rotate 90 1 0 0
    Shape "bilinearmesh" "point3 P" [-2 -2 0  2 -2 0  -2 2 0  2 2 0] "point2 uv" [0 0 1 0 0 1 1 1]
AttributeEnd
ObjectBegin "ball"
    Material "conductor" "spectrum eta" "metal-Au-eta" "spectrum k" "metal-Au-k" "float roughness" 0.1
    Shape "sphere" "float radius" 0.3
ObjectEnd
AttributeBegin
    Translate -0.8 0.3 0
    ObjectInstance "ball"
AttributeEnd
AttributeBegin
    Material "dielectric" "float eta" 1.5
    Translate 0.8 0.3 0
    Scale 0.3 0.3 0.3
    Shape "trianglemesh" "point3 P" [0 0 0 1 0 0 0 1 0 0 0 1] "integer indices" [0 2 1 0 1 3 0 3 2 1 2 3]
AttributeEnd
Material "mix" "string materials" ["checks" "plain"] "float amount" 0.3
Shape "plymesh" "string filename" "quad.ply"
"#;

const MATERIALS_PBRT: &str = r#"Texture "c" "spectrum" "checkerboard" "rgb tex1" [0.8 0.8 0.8] "rgb tex2" [0.2 0.3 0.4] "float uscale" 4 "float vscale" 4
MakeNamedMaterial "checks" "string type" "diffuse" "texture reflectance" "c"
MakeNamedMaterial "plain" "string type" "coateddiffuse" "rgb reflectance" [0.5 0.4 0.3] "float roughness" 0.05
"#;

pub fn seeds() -> Vec<Seed> {
    let xml_files = || {
        vec![
            text("scene.xml", SCENE_XML),
            text("materials.xml", MATERIALS_XML),
            text("cube.obj", CUBE_OBJ),
            text("cube.mtl", CUBE_MTL),
            text("quad.ply", &ply_ascii()),
        ]
    };
    let (buf, ..) = gltf_buffer();
    let pbrt_files = || {
        vec![
            text("scene.pbrt", SCENE_PBRT),
            text("materials.pbrt", MATERIALS_PBRT),
            text("quad.ply", &ply_ascii()),
        ]
    };
    vec![
        seed("pbrt", "scene.pbrt", "scene.pbrt", pbrt_files()),
        seed("pbrt-include", "scene.pbrt", "materials.pbrt", pbrt_files()),
        seed("xml", "scene.xml", "scene.xml", xml_files()),
        seed("xml-include", "scene.xml", "materials.xml", xml_files()),
        seed("xml-obj", "scene.xml", "cube.obj", xml_files()),
        seed(
            "obj",
            "cube.obj",
            "cube.obj",
            vec![text("cube.obj", CUBE_OBJ), text("cube.mtl", CUBE_MTL)],
        ),
        seed(
            "mtl",
            "cube.obj",
            "cube.mtl",
            vec![text("cube.obj", CUBE_OBJ), text("cube.mtl", CUBE_MTL)],
        ),
        seed(
            "ply-ascii",
            "quad.ply",
            "quad.ply",
            vec![text("quad.ply", &ply_ascii())],
        ),
        seed(
            "ply-binary",
            "quad.ply",
            "quad.ply",
            vec![binary("quad.ply", ply_binary())],
        ),
        seed(
            "gltf",
            "quad.gltf",
            "quad.gltf",
            vec![
                text("quad.gltf", &gltf_json(Some("quad.bin"))),
                binary("quad.bin", buf.clone()),
            ],
        ),
        seed(
            "gltf-bin",
            "quad.gltf",
            "quad.bin",
            vec![
                text("quad.gltf", &gltf_json(Some("quad.bin"))),
                binary("quad.bin", buf),
            ],
        ),
        seed(
            "glb",
            "quad.glb",
            "quad.glb",
            vec![binary("quad.glb", glb())],
        ),
    ]
}

/// Numbers that loaders must not trust.
const NUMBERS: &[&str] = &[
    "nan",
    "NaN",
    "inf",
    "-inf",
    "-1",
    "0",
    "-0",
    "1e38",
    "-1e38",
    "1e-45",
    "4294967295",
    "2147483648",
    "99999999999999999999",
    "65536",
    "1e9",
    "0.5",
    "-3",
    "1e400",
];

/// Words loaders must not trust, as little-endian u32 bit patterns.
const WORDS: &[u32] = &[
    0,
    1,
    0xFFFF_FFFF,
    0x7FFF_FFFF,
    0x8000_0000,
    0x0001_0000,
    0x7FC0_0000, // f32 NaN
    0x7F80_0000, // f32 +inf
    0xFF80_0000, // f32 -inf
    0xF149_F2CA, // f32 -1e30
];

/// Applies 1–4 random operators (1 in half the cases) to the seed's target file.
pub fn case(seeds: &[Seed], run_seed: u64, index: u64) -> Case {
    let mut rng = Rng::new(run_seed ^ index.wrapping_mul(0xa076_1d64_78bd_642f));
    let s = &seeds[rng.below(seeds.len())];
    let mut files = s.files.clone();
    let f = files
        .iter_mut()
        .find(|f| f.name == s.target)
        .expect("target file");
    // half the cases carry one mutation, so that more of them get past
    // the first check and reach deeper code
    let n = if rng.below(2) == 0 {
        1
    } else {
        2 + rng.below(3)
    };
    let mut ops = Vec::new();
    for _ in 0..n {
        ops.push(mutate(&mut rng, &mut f.bytes, f.text));
    }
    Case {
        label: s.label,
        main: s.main.clone(),
        files,
        ops,
    }
}

/// Byte ranges of the numeric tokens of a text file.
fn number_spans(b: &[u8]) -> Vec<(usize, usize)> {
    let mut spans = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let starts =
            b[i].is_ascii_digit() || (b[i] == b'-' && i + 1 < b.len() && b[i + 1].is_ascii_digit());
        if starts && (i == 0 || !b[i - 1].is_ascii_alphanumeric()) {
            let j0 = i;
            i += 1;
            while i < b.len()
                && (b[i].is_ascii_digit() || matches!(b[i], b'.' | b'e' | b'E' | b'-' | b'+'))
            {
                i += 1;
            }
            spans.push((j0, i));
        } else {
            i += 1;
        }
    }
    spans
}

fn line_spans(b: &[u8]) -> Vec<(usize, usize)> {
    let mut spans = Vec::new();
    let mut start = 0;
    for (i, &c) in b.iter().enumerate() {
        if c == b'\n' {
            spans.push((start, i + 1));
            start = i + 1;
        }
    }
    if start < b.len() {
        spans.push((start, b.len()));
    }
    spans
}

/// One operator on `b`; returns its description.
fn mutate(rng: &mut Rng, b: &mut Vec<u8>, text: bool) -> String {
    if b.is_empty() {
        b.push(b'0');
        return "refill".into();
    }
    // text: numbers are replaced in 5 of 12 draws, since a damaged number
    // keeps the syntax and so reaches the code that trusts it
    let op = rng.below(if text { 12 } else { 6 });
    match (text, op) {
        (_, 0) => {
            let i = rng.below(b.len());
            b[i] ^= 1 << rng.below(8);
            format!("flip bit at {i}")
        }
        (_, 1) => {
            let at = rng.below(b.len() + 1);
            b.truncate(at);
            format!("truncate at {at}")
        }
        (_, 2) => {
            let i = rng.below(b.len());
            let len = (1 + rng.below(64)).min(b.len() - i);
            b.drain(i..i + len);
            format!("delete {len} bytes at {i}")
        }
        (_, 3) => {
            let i = rng.below(b.len());
            let len = (1 + rng.below(256)).min(b.len() - i);
            let times = 1 + rng.below(8);
            let chunk: Vec<u8> = b[i..i + len].to_vec();
            for _ in 0..times {
                b.splice(i..i, chunk.iter().copied());
            }
            format!("repeat {len} bytes at {i} {times} more times")
        }
        (false, _) => {
            // overwrite an aligned little-endian word: headers and counts
            let words = b.len() / 4;
            if words == 0 {
                return "no word".into();
            }
            let i = 4 * rng.below(words);
            let w = if rng.below(4) == 0 {
                (b.len() as u32).wrapping_add(rng.below(3) as u32)
            } else {
                *rng.pick(WORDS)
            };
            b[i..i + 4].copy_from_slice(&w.to_le_bytes());
            format!("word {w:#x} at {i}")
        }
        (true, 4..=8) => {
            let spans = number_spans(b);
            if spans.is_empty() {
                return "no number".into();
            }
            let (s, e) = *rng.pick(&spans);
            let v = *rng.pick(NUMBERS);
            b.splice(s..e, v.bytes());
            format!("number at {s} -> {v}")
        }
        (true, 9) | (true, 10) => {
            let lines = line_spans(b);
            let (s, e) = *rng.pick(&lines);
            if rng.below(2) == 0 {
                b.drain(s..e);
                format!("delete line at {s}")
            } else {
                let times = 1 + rng.below(20);
                let line: Vec<u8> = b[s..e].to_vec();
                for _ in 0..times {
                    b.splice(s..s, line.iter().copied());
                }
                format!("repeat line at {s} {times} times")
            }
        }
        _ => {
            let lines = line_spans(b);
            let a = *rng.pick(&lines);
            let c = *rng.pick(&lines);
            let (x, y) = if a.0 <= c.0 { (a, c) } else { (c, a) };
            if x.1 > y.0 {
                return "swap nothing".into();
            }
            let (l1, l2) = (b[x.0..x.1].to_vec(), b[y.0..y.1].to_vec());
            let mut out = b[..x.0].to_vec();
            out.extend_from_slice(&l2);
            out.extend_from_slice(&b[x.1..y.0]);
            out.extend_from_slice(&l1);
            out.extend_from_slice(&b[y.1..]);
            *b = out;
            format!("swap lines at {} and {}", x.0, y.0)
        }
    }
}
