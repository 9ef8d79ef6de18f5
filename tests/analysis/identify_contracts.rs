//! The artefact input contracts of `retrocomp identify` (docs/identify.md): readers accept what the
//! docs state, report every problem with file and line, and the writers round-trip.

use retrocomp_analysis::identify::contracts::{Plane, read_ballbar, read_hole_plate};

const PLATE_SIDE: &str = "kind = \"hole_plate\"\nplane = \"xz\"\nalpha_ppm_per_K = 11.5\ncertificate_uncertainty_um = 0.1\n";

#[test]
fn hole_plate_reads_required_and_optional_columns() {
    let csv = "hole,u_mm,v_mm,x_mm,y_mm,z_mm\n\
               a,0,0,100,50,20\n\
               b,40,0,140.001,50,20\n\
               c,0,40,100,50,60.002\n";
    let p = read_hole_plate("P1", csv, PLATE_SIDE).unwrap();
    assert_eq!(p.plane, Plane::Xz);
    assert_eq!(p.plane.axes(), [0, 2]);
    assert_eq!(p.probes.len(), 3);
    assert_eq!(p.probes[1].pos_mm, [140.001, 50.0, 20.0]);
    assert_eq!(p.probes[1].tool_mm, 0.0, "tool_mm absent = 0");
    assert_eq!(p.probes[2].line, 4);
    assert_eq!(p.alpha_ppm_per_k, 11.5);
    let (csv2, side2) = p.to_texts();
    let q = read_hole_plate("P1", &csv2, &side2).unwrap();
    assert_eq!(q.probes.len(), 3);
    assert_eq!(q.probes[2].pos_mm, p.probes[2].pos_mm);
    assert_eq!(q.plane, p.plane);
}

#[test]
fn hole_plate_errors_name_file_line_and_expectation() {
    let csv = "hole,u_mm,v_mm,x_mm,y_mm,z_mm,tool_mm,repeat,T_scale_x_C\n\
               a,0,0,100,50,20,100,0,20.5\n\
               b,forty,0,140,50,20,100,0,20.5\n\
               c,0,40,100,50,,100,x,20.5\n";
    let side = "kind = \"hole_plate\"\nplane = \"xw\"\nalpha_ppm_per_K = \"a lot\"\n";
    let e = read_hole_plate("dir/P2", csv, side)
        .unwrap_err()
        .to_string();
    for want in [
        "dir/P2.toml:2: key `plane`: \"xw\", expected \"xy\", \"xz\" or \"yz\"",
        "dir/P2.toml:3: key `alpha_ppm_per_K`: expected a number",
        "dir/P2.toml:1: key `certificate_uncertainty_um` missing",
        "dir/P2.csv:2: scale temperature given: the side file needs `scale_alpha_ppm_per_K`",
        "dir/P2.csv:3: column `u_mm`: `forty` is not a finite number",
        "dir/P2.csv:4: column `z_mm`: empty, expected a number",
        "dir/P2.csv:4: column `repeat`: `x` is not a count",
    ] {
        assert!(e.contains(want), "missing `{want}` in:\n{e}");
    }
    let e = read_hole_plate("P3", "hole,u_mm,x_mm\n", PLATE_SIDE)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("P3.csv:1: header: missing column(s) v_mm, y_mm, z_mm"),
        "{e}"
    );
}

#[test]
fn ballbar_reads_and_reports() {
    let side = "kind = \"ballbar\"\nr_nom_mm = 150\ncentre_mm = [400.0, 250.0, 150]\nalpha_ppm_per_K = 11.5\n";
    let csv = "point,x_mm,y_mm,z_mm,dr_um,tool_mm,T_bar_C\n\
               p0,400,250,300,1.5,110,20.3\n\
               p1,550,250,150,-0.5,110,20.3\n\
               p2,400,400,150,0.2,110,20.3\n\
               p3,250,250,150,0.9,110,20.3\n";
    let b = read_ballbar("S1", csv, side).unwrap();
    assert_eq!(b.centre_mm, [400.0, 250.0, 150.0]);
    assert_eq!(b.points.len(), 4);
    assert_eq!(b.points[0].dr_um, 1.5);
    assert_eq!(b.points[0].t_bar_c, Some(20.3));
    let (c2, s2) = b.to_texts();
    assert_eq!(read_ballbar("S1", &c2, &s2).unwrap().points, {
        let mut p = b.points.clone();
        for (i, x) in p.iter_mut().enumerate() {
            x.line = i + 2;
        }
        p
    });
    let bad_side = "kind = \"hole_plate\"\nr_nom_mm = -3\ncentre_mm = [1, 2]\nalpha_ppm_per_K = 11.5\ncolour = 1\n";
    let e = read_ballbar("S2", "point,x_mm\n", bad_side)
        .unwrap_err()
        .to_string();
    for want in [
        "S2.toml:1: key `kind`: is \"hole_plate\", expected \"ballbar\"",
        "S2.toml:2: key `r_nom_mm`: expected > 0",
        "S2.toml:3: key `centre_mm`: expected [x, y, z] numbers",
        "S2.toml:5: unknown key `colour`",
        "S2.csv:1: header: missing column(s) y_mm, z_mm, dr_um",
    ] {
        assert!(e.contains(want), "missing `{want}` in:\n{e}");
    }
}
