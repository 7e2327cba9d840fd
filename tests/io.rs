//! Readers and writers: every format on literal fixtures, round trips through the writers, and the corpus
//! of bad files, each of which must fail with its stable code, the file name and a line/byte location.

mod common;

use common::{file, gz, read, read_cloud, read_mesh, scratch};
use scanstation::geometry::io::{
    ReadOptions, VertexAttributes, ensure_not_input, read_geometry, write_obj, write_ply, write_ply_cloud,
};
use scanstation::geometry::shapes::icosphere;
use scanstation::geometry::topology::TopologyReport;
use scanstation::{ErrorCode, Location, PointCloud, PolyMesh};

/// A unit square split into two triangles, plus a quad above it (two faces of degree 3 and one of 4).
fn expect_square_mesh(m: &PolyMesh, what: &str) {
    assert_eq!(m.positions.len(), 4, "{what}: vertices");
    assert_eq!(m.positions[2], [1.0, 1.0, 0.0], "{what}: vertex order and property order");
    let faces: Vec<Vec<u32>> = m.faces().map(|f| f.to_vec()).collect();
    assert_eq!(faces, vec![vec![0, 1, 2], vec![0, 2, 3], vec![0, 1, 2, 3]], "{what}: faces");
}

const PLY_ASCII: &str = "ply\nformat ascii 1.0\ncomment odd property order, extra properties, extra elements\n\
element vertex 4\nproperty float z\nproperty float confidence\nproperty double x\nproperty float y\n\
element range_grid 2\nproperty list uchar int vertex_indices\n\
element face 3\nproperty uchar flags\nproperty list ushort uint vertex_indices\nend_header\n\
0 1 0 0\n0 .5 1 0\n0 .5 1 1\n0 .5 0 1\n\
1 3\n0\n\
7 3 0 1 2\n7 3 0 2 3\n7 4 0 1 2 3\n";

/// The same content as `PLY_ASCII`, binary, in either byte order.
fn ply_binary(big: bool) -> Vec<u8> {
    let enc = if big { "binary_big_endian" } else { "binary_little_endian" };
    let mut v = format!(
        "ply\nformat {enc} 1.0\nelement vertex 4\nproperty float z\nproperty float confidence\nproperty double x\n\
property float y\nelement range_grid 2\nproperty list uchar int vertex_indices\nelement face 3\n\
property uchar flags\nproperty list ushort uint vertex_indices\nend_header\n"
    )
    .into_bytes();
    let f32b = |x: f32| if big { x.to_be_bytes() } else { x.to_le_bytes() };
    let f64b = |x: f64| if big { x.to_be_bytes() } else { x.to_le_bytes() };
    let u16b = |x: u16| if big { x.to_be_bytes() } else { x.to_le_bytes() };
    let u32b = |x: u32| if big { x.to_be_bytes() } else { x.to_le_bytes() };
    for (x, y) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
        v.extend(f32b(0.0));
        v.extend(f32b(0.5));
        v.extend(f64b(x));
        v.extend(f32b(y));
    }
    v.push(1);
    v.extend(u32b(3));
    v.push(0);
    for face in [&[0u32, 1, 2][..], &[0, 2, 3], &[0, 1, 2, 3]] {
        v.push(7);
        v.extend(u16b(face.len() as u16));
        for &i in face {
            v.extend(u32b(i));
        }
    }
    v
}

#[test]
fn ply_ascii_and_binary_both_endiannesses_agree() {
    let dir = scratch("ply_variants");
    expect_square_mesh(&read_mesh(&file(&dir, "a.ply", PLY_ASCII)), "ascii");
    expect_square_mesh(&read_mesh(&file(&dir, "le.ply", ply_binary(false))), "binary LE");
    expect_square_mesh(&read_mesh(&file(&dir, "be.ply", ply_binary(true))), "binary BE");
    expect_square_mesh(&read_mesh(&file(&dir, "le.ply.gz", gz(&ply_binary(false)))), "gzip by name");
    expect_square_mesh(&read_mesh(&file(&dir, "le_gz_no_suffix.ply", gz(&ply_binary(false)))), "gzip by magic");
}

#[test]
fn ply_faces_before_vertices_and_crlf_header() {
    let dir = scratch("ply_order");
    let text = "ply\r\nformat ascii 1.0\r\nelement face 1\r\nproperty list uchar int vertex_index\r\n\
element vertex 3\r\nproperty float x\r\nproperty float y\r\nproperty float z\r\nend_header\r\n\
3 2 1 0\r\n0 0 0\r\n1 0 0\r\n0 1 0\r\n";
    let m = read_mesh(&file(&dir, "f.ply", text));
    assert_eq!(m.face(0), &[2, 1, 0]);
    assert_eq!(m.positions[1], [1.0, 0.0, 0.0]);
}

#[test]
fn ply_cloud_keeps_normals_and_colors() {
    let dir = scratch("ply_cloud");
    let text = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
property float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\n\
property uchar blue\nend_header\n1 2 3 0 0 1 255 0 10\n4 5 6 1 0 0 0 128 0\n";
    let c = read_cloud(&file(&dir, "c.ply", text));
    assert_eq!(c.positions, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    assert_eq!(c.normals.unwrap()[1], [1.0, 0.0, 0.0]);
    assert_eq!(c.colors.unwrap(), vec![[255, 0, 10], [0, 128, 0]]);
}

#[test]
fn obj_keeps_polygons_and_resolves_relative_indices() {
    let dir = scratch("obj");
    let text = "# comment\nmtllib x.mtl\no square\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0 1.0\nvt 0 0\nvn 0 0 1\n\
g a\nusemtl m\ns off\nf 1/1/1 2/1/1 3/1/1\nf -4//1 -2//1 -1//1\nf 1 2 3 4\nl 1 2\n";
    expect_square_mesh(&read_mesh(&file(&dir, "sq.obj", text)), "obj");
    let cloud = read_cloud(&file(&dir, "pts.obj", "v 1 2 3\nv 4 5 6\n"));
    assert_eq!(cloud.positions.len(), 2);
}

#[test]
fn stl_ascii_and_binary_are_welded_into_the_same_closed_mesh() {
    let dir = scratch("stl");
    let cube = scanstation::geometry::shapes::cuboid([0.0; 3], [1.0, 2.0, 3.0]);
    let mut ascii = String::from("solid cube\n");
    let mut bin = vec![0u8; 80];
    bin[..5].copy_from_slice(b"solid"); // binary files that start with "solid" exist in the wild
    bin.extend((cube.triangles.len() as u32).to_le_bytes());
    for t in &cube.triangles {
        ascii.push_str("  facet normal 0 0 0\n    outer loop\n");
        bin.extend([0u8; 12]);
        for &i in t {
            let p = cube.positions[i as usize];
            ascii.push_str(&format!("      vertex {} {} {}\n", p[0], p[1], p[2]));
            p.iter().for_each(|c| bin.extend(c.to_le_bytes()));
        }
        ascii.push_str("    endloop\n  endfacet\n");
        bin.extend([0u8; 2]);
    }
    ascii.push_str("endsolid cube\n");
    for (name, bytes) in [("a.stl", ascii.into_bytes()), ("b.stl", bin)] {
        let m = read_mesh(&file(&dir, name, bytes));
        let r = TopologyReport::compute(&m);
        assert_eq!((r.vertices, r.faces, r.closed, r.euler_characteristic), (8, 12, true, 2), "{name}");
        assert!((r.volume.unwrap() - 6.0).abs() < 1e-12, "{name}: volume {:?}", r.volume);
    }
}

#[test]
fn off_variants() {
    let dir = scratch("off");
    let quad_cube = "OFF\n# a cube of quads\n8 6 12\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n0 0 1\n1 0 1\n1 1 1\n0 1 1\n\
4 0 3 2 1\n4 4 5 6 7\n4 0 1 5 4\n4 2 3 7 6\n4 1 2 6 5\n4 0 4 7 3\n";
    let m = read_mesh(&file(&dir, "cube.off", quad_cube));
    let r = TopologyReport::compute(&m);
    assert_eq!(r.faces_by_degree.get(&4), Some(&6));
    assert!(r.closed && r.consistently_oriented);
    assert!((r.volume.unwrap() - 1.0).abs() < 1e-12, "volume {:?}", r.volume);
    let coff = "COFF 3 1 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0 255\n0 1 0 0 0 255 255\n3 0 1 2 10 20 30\n";
    assert_eq!(read_mesh(&file(&dir, "c.off", coff)).face_count(), 1);
}

#[test]
fn xyz_and_pts_clouds() {
    let dir = scratch("xyz");
    let c = read_cloud(&file(&dir, "a.xyz", "# x y z\n1 2 3\n4 5 6\n"));
    assert_eq!(c.positions, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    let c = read_cloud(&file(&dir, "n.xyz", "1,2,3,0,0,1\n4;5;6;0;1;0\n"));
    assert_eq!(c.normals.unwrap()[1], [0.0, 1.0, 0.0]);
    let c = read_cloud(&file(&dir, "scan.pts", "2\n1 2 3 -1200 10 20 30\n4 5 6 -1100 40 50 60\n"));
    assert_eq!(c.colors.unwrap()[1], [40, 50, 60]);
}

#[test]
fn writers_round_trip() {
    let dir = scratch("write");
    let sphere = PolyMesh::from(icosphere(2.5, 2, [1.0, -2.0, 3.0]));
    let n = sphere.positions.len();
    let colors: Vec<[u8; 3]> = (0..n).map(|i| [i as u8, 0, 255]).collect();
    let scalar: Vec<f32> = (0..n).map(|i| i as f32 * 0.5).collect();
    let attrs = VertexAttributes { colors: Some(&colors), scalar: Some(("distance", &scalar)), normals: None };
    let ply = dir.join("s.ply");
    write_ply(&ply, &sphere, &attrs, &["a comment"]).unwrap();
    assert_eq!(read_mesh(&ply), sphere, "binary PLY round trip");
    let text = std::fs::read(&ply).unwrap();
    let header = String::from_utf8_lossy(&text[..400]);
    assert!(header.contains("property float distance") && header.contains("property uchar red"), "{header}");

    let quads = PolyMesh::new(
        vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [2.0, 0.5, 0.1]],
        &[vec![0, 1, 2, 3], vec![1, 4, 2]],
    )
    .unwrap();
    let obj = dir.join("q.obj");
    write_obj(&obj, &quads).unwrap();
    assert_eq!(read_mesh(&obj), quads, "OBJ round trip keeps quads");

    let cloud = PointCloud::new(vec![[0.1, 0.2, 0.3]; 3], Some(vec![[0.0, 0.0, 1.0]; 3]), None).unwrap();
    let cp = dir.join("c.ply");
    write_ply_cloud(&cp, &cloud, &VertexAttributes::default(), &[]).unwrap();
    assert_eq!(read_cloud(&cp), cloud);
    // No temporary files are left behind.
    let leftovers: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

#[test]
fn outputs_never_overwrite_inputs() {
    let dir = scratch("no_overwrite");
    let input = file(&dir, "scan.ply", PLY_ASCII);
    let e = ensure_not_input(&input, &[&input]).unwrap_err();
    assert_eq!(e.code, ErrorCode::ResourceOutput);
    assert!(ensure_not_input(&dir.join("other.ply"), &[&input]).is_ok());
    assert_eq!(std::fs::read_to_string(&input).unwrap(), PLY_ASCII);
}

#[test]
fn memory_budget_is_enforced_before_allocating() {
    let dir = scratch("budget");
    let mut text = String::from(
        "ply\nformat ascii 1.0\nelement vertex 1000\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
    );
    for i in 0..1000 {
        text.push_str(&format!("{i} 0 0\n"));
    }
    let p = file(&dir, "v.ply", text);
    let e = read_geometry(&p, &ReadOptions { memory_budget: 1000, ..Default::default() }).unwrap_err();
    assert_eq!(e.code, ErrorCode::ResourceMemoryBudget, "{e}");
    assert_eq!(read_geometry(&p, &ReadOptions::default()).unwrap().positions().len(), 1000);
}

/// Where a bad file's error must point.
#[derive(Debug)]
enum At {
    Line(u64),
    Byte(u64),
    AnyLine,
    AnyByte,
    Nowhere,
}

/// The corpus of bad files: (name, content, expected code, expected location).
fn bad_files() -> Vec<(&'static str, Vec<u8>, ErrorCode, At)> {
    use ErrorCode::*;
    let hdr = |body: &str| format!("ply\nformat ascii 1.0\n{body}end_header\n");
    let vtx3 = "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n";
    let tri = "element face 1\nproperty list uchar int vertex_indices\n";
    let le = |body: &str| format!("ply\nformat binary_little_endian 1.0\n{body}end_header\n").into_bytes();
    let mut truncated_binary = le(vtx3);
    truncated_binary.extend([0u8; 20]); // 3 vertices need 36 bytes
    let mut inf_binary = le(vtx3);
    [0.0f32, 0.0, 0.0, 1.0, f32::INFINITY, 0.0, 0.0, 1.0, 0.0].iter().for_each(|c| inf_binary.extend(c.to_le_bytes()));
    let inf_offset = le(vtx3).len() as u64 + 12;
    let mut huge_list = le(&format!("{vtx3}element face 1\nproperty list int int vertex_indices\n"));
    [0.0f32; 9].iter().for_each(|c| huge_list.extend(c.to_le_bytes()));
    huge_list.extend(1_000_000_000i32.to_le_bytes());
    let huge_list_at = huge_list.len() as u64 - 4;
    let mut stl_absurd = vec![0u8; 80];
    stl_absurd.extend(1_000_000_000u32.to_le_bytes());
    stl_absurd.extend([0u8; 116]);
    let good_gz = gz(PLY_ASCII.as_bytes());
    let cut_gz = good_gz[..good_gz.len() / 2].to_vec();
    let v = |s: String| s.into_bytes();
    vec![
        ("empty.ply", vec![], InputEmpty, At::Nowhere),
        ("blank.xyz", b"  \n\n ".to_vec(), InputEmpty, At::Nowhere),
        ("junk.bin", vec![0, 159, 146, 150, 1, 2, 3], InputUnknownFormat, At::Nowhere),
        ("no_magic.ply", b"PLY\nformat ascii 1.0\nend_header\n".to_vec(), InputBadHeader, At::Line(1)),
        ("no_format.ply", b"ply\nelement vertex 0\nend_header\n".to_vec(), InputBadHeader, At::AnyLine),
        ("bad_type.ply", v(hdr("element vertex 1\nproperty flot x\n")), InputBadHeader, At::Line(4)),
        ("no_end_header.ply", b"ply\nformat ascii 1.0\nelement vertex 1\n".to_vec(), InputTruncated, At::Line(4)),
        ("lying_count.ply", v(hdr(vtx3) + "0 0 0\n1 0 0\n"), InputTruncated, At::Line(10)),
        (
            "absurd_faces.ply",
            v(hdr(&format!("{vtx3}element face 2147483648\nproperty list uchar int vertex_indices\n"))
                + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"),
            InputAbsurdCount,
            At::AnyLine,
        ),
        ("nan.ply", v(hdr(vtx3) + "0 0 0\nnan 0 0\n0 1 0\n"), InputNonFinite, At::Line(9)),
        ("inf_binary.ply", inf_binary, InputNonFinite, At::Byte(inf_offset)),
        ("bad_number.ply", v(hdr(vtx3) + "0 0 0\n1.0abc 0 0\n0 1 0\n"), InputBadNumber, At::Line(9)),
        ("extra_values.ply", v(hdr(vtx3) + "0 0 0 7\n1 0 0\n0 1 0\n"), InputBadRecord, At::Line(8)),
        (
            "index_out_of_range.ply",
            v(hdr(&format!("{vtx3}{tri}")) + "0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n"),
            InputBadIndex,
            At::Nowhere,
        ),
        (
            "negative_index.ply",
            v(hdr(&format!("{vtx3}{tri}")) + "0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n"),
            InputBadIndex,
            At::Line(13),
        ),
        (
            "two_vertex_face.ply",
            v(hdr(&format!("{vtx3}{tri}")) + "0 0 0\n1 0 0\n0 1 0\n2 0 1\n"),
            InputBadFace,
            At::Line(13),
        ),
        ("truncated_binary.ply", truncated_binary, InputTruncated, At::AnyByte),
        ("huge_list.ply", huge_list, InputAbsurdCount, At::Byte(huge_list_at)),
        ("zero_index.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n".to_vec(), InputBadIndex, At::Line(4)),
        ("short_vertex.obj", b"v 0 0\n".to_vec(), InputBadRecord, At::Line(1)),
        ("forward_index.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n".to_vec(), InputBadIndex, At::Nowhere),
        ("absurd.stl", stl_absurd, InputAbsurdCount, At::Byte(80)),
        (
            "two_corner_facet.stl",
            b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nendloop\nendfacet\nendsolid\n"
                .to_vec(),
            InputBadFace,
            At::Line(6),
        ),
        ("short.off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n".to_vec(), InputTruncated, At::Line(5)),
        ("bad_index.off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n".to_vec(), InputBadIndex, At::Line(6)),
        ("absurd.off", b"OFF\n99999999999 1 0\n0 0 0\n".to_vec(), InputAbsurdCount, At::Line(2)),
        ("ragged.xyz", b"1 2 3\n4 5 6 7\n".to_vec(), InputBadRecord, At::Line(2)),
        ("five_columns.xyz", b"1 2 3 4 5\n".to_vec(), InputBadRecord, At::Line(1)),
        ("short.pts", b"3\n1 2 3\n4 5 6\n".to_vec(), InputTruncated, At::Line(1)),
        ("inf.xyz", b"1 2 3\n1e39 0 0\n".to_vec(), InputNonFinite, At::Line(2)),
        ("cut.ply.gz", cut_gz, InputTruncated, At::Nowhere),
    ]
}

#[test]
fn bad_files_fail_with_stable_codes_and_locations() {
    let dir = scratch("bad");
    for (name, bytes, code, at) in bad_files() {
        let p = file(&dir, name, &bytes);
        let e = match read(&p) {
            Ok(g) => panic!("{name}: read succeeded ({} vertices); expected {code}", g.positions().len()),
            Err(e) => e,
        };
        assert_eq!(e.code, code, "{name}: {e}");
        assert_eq!(e.file.as_deref(), Some(p.as_path()), "{name}: the error must name the file: {e}");
        match (&at, e.location) {
            (At::Line(l), Some(Location::Line(got))) => assert_eq!(got, *l, "{name}: {e}"),
            (At::Byte(b), Some(Location::Byte(got))) => assert_eq!(got, *b, "{name}: {e}"),
            (At::AnyLine, Some(Location::Line(_))) | (At::AnyByte, Some(Location::Byte(_))) | (At::Nowhere, _) => {}
            (want, got) => panic!("{name}: location {got:?}, expected {want:?}: {e}"),
        }
        assert!(!e.to_string().is_empty());
        assert_eq!(std::fs::read(&p).unwrap(), bytes, "{name}: the input must be left as it was");
    }
    let missing = read(&dir.join("does_not_exist.ply")).unwrap_err();
    assert_eq!(missing.code, ErrorCode::InputNotFound);
}

mod never_panics {
    //! Truncated and corrupted versions of valid files: the reader returns a value or an error, never panics.
    use super::*;
    use proptest::prelude::*;

    fn seeds() -> Vec<(&'static str, Vec<u8>)> {
        vec![
            ("a.ply", PLY_ASCII.as_bytes().to_vec()),
            ("le.ply", ply_binary(false)),
            ("be.ply", ply_binary(true)),
            ("s.obj", b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf -4 -2 -1\nf 1/1 2/2 3/3 4/4\n".to_vec()),
            ("s.off", b"OFF\n4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n".to_vec()),
            ("s.xyz", b"1 2 3\n4 5 6\n7 8 9\n".to_vec()),
            ("s.stl", b"solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid s\n".to_vec()),
            ("g.ply.gz", gz(&ply_binary(false))),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

        #[test]
        fn corrupted_inputs_give_errors_not_panics(
            which in 0usize..8,
            cut in any::<prop::sample::Index>(),
            flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 0..4),
        ) {
            let (name, mut bytes) = seeds().swap_remove(which);
            for (at, byte) in flips {
                let i = at.index(bytes.len());
                bytes[i] = byte;
            }
            bytes.truncate(cut.index(bytes.len() + 1));
            let dir = scratch(&format!("fuzz_{}", std::thread::current().name().unwrap_or("t").replace("::", "_")));
            let p = file(&dir, name, &bytes);
            if let Err(e) = read(&p) {
                prop_assert_eq!(e.file.as_deref(), Some(p.as_path()));
            }
        }
    }
}
