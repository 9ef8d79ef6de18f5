//! A real headless LinuxCNC 2.9 (uspace, POSIX non-realtime, no X): a generated INI with three
//! trivkins joints homed in place (`HOME_SEARCH_VEL = 0`), motor feedback looped back in HAL, an
//! NML file without `TCP=5005` (nothing listens beyond loopback), and as `[DISPLAY]DISPLAY` a
//! Python script (Debian's /usr/bin/python3, which has the `linuxcnc` module) that resets estop,
//! turns the machine on, homes, runs MDI lines and after each records HAL pins read with
//! `halcmd -s getp` once they stop changing (the comp correction is rate-limited). LinuxCNC ends
//! when the script exits. `rtapi_app` refuses to run as root: as root the run is started as
//! `nobody` (`setpriv --reuid=65534`) in a world-writable folder.

use std::path::{Path, PathBuf};
use std::process::Command;

/// Per-joint INI lines added to `[JOINT_n]` (e.g. `COMP_FILE = …`).
pub(crate) struct Config {
    pub joint_extra: [Vec<String>; 3],
    /// HAL pins read after every MDI line.
    pub pins: Vec<String>,
}

const DISPLAY_PY: &str = r#"#!/usr/bin/python3
import linuxcnc, subprocess, sys, time, os
s = linuxcnc.stat(); c = linuxcnc.command()
here = os.path.dirname(os.path.abspath(__file__))
out = open(os.path.join(here, "result.txt"), "w")
pins = [p.strip() for p in open(os.path.join(here, "pins.txt")) if p.strip()]
def getp(n):
    return subprocess.check_output(["halcmd", "-s", "getp", n]).decode().split()[0]
def until(cond, what, t=60):
    end = time.time() + t
    while time.time() < end:
        s.poll()
        if cond(): return
        time.sleep(0.02)
    out.write("TIMEOUT %s\n" % what); out.flush(); sys.exit(1)
c.state(linuxcnc.STATE_ESTOP_RESET); until(lambda: s.task_state == linuxcnc.STATE_ESTOP_RESET, "estop reset")
c.state(linuxcnc.STATE_ON); until(lambda: s.task_state == linuxcnc.STATE_ON, "machine on")
c.mode(linuxcnc.MODE_MANUAL); c.wait_complete()
c.teleop_enable(0); c.wait_complete()
c.home(-1); until(lambda: all(s.homed[j] for j in range(s.joints)), "homed")
c.mode(linuxcnc.MODE_MDI); c.wait_complete()
for line in open(os.path.join(here, "mdi.txt")):
    line = line.strip()
    if not line: continue
    c.mdi(line); c.wait_complete(120)
    until(lambda: s.inpos and s.state == linuxcnc.RCS_DONE, "in position after " + line)
    last = None
    for i in range(2000):
        v = [getp(p) for p in pins]
        if v == last: break
        last = v; time.sleep(0.02)
    else:
        out.write("TIMEOUT settle %s\n" % line); out.flush(); sys.exit(1)
    out.write("%s\t%s\n" % (line, "\t".join(v))); out.flush()
out.write("DONE\n"); out.close()
"#;

const CORE_HAL: &str = "loadrt [KINS]KINEMATICS
loadrt [EMCMOT]EMCMOT servo_period_nsec=[EMCMOT]SERVO_PERIOD num_joints=[KINS]JOINTS
addf motion-command-handler servo-thread
addf motion-controller servo-thread
net j0 joint.0.motor-pos-cmd => joint.0.motor-pos-fb
net j1 joint.1.motor-pos-cmd => joint.1.motor-pos-fb
net j2 joint.2.motor-pos-cmd => joint.2.motor-pos-fb
net estop-loop iocontrol.0.user-enable-out => iocontrol.0.emc-enable-in
net tool-prep iocontrol.0.tool-prepare => iocontrol.0.tool-prepared
net tool-change iocontrol.0.tool-change => iocontrol.0.tool-changed
";

fn ini(dir: &Path, cfg: &Config) -> String {
    let d = dir.display();
    let mut s = format!(
        "[EMC]\nVERSION = 1.1\nMACHINE = retrocomp-test\nNML_FILE = {d}/loopback.nml\n\
[DISPLAY]\nDISPLAY = {d}/display.py\n[TASK]\nTASK = milltask\nCYCLE_TIME = 0.010\n\
[RS274NGC]\nPARAMETER_FILE = sim.var\n[EMCMOT]\nEMCMOT = motmod\nCOMM_TIMEOUT = 1.0\nSERVO_PERIOD = 1000000\n\
[EMCIO]\nEMCIO = io\nCYCLE_TIME = 0.100\nTOOL_TABLE = tool.tbl\n[HAL]\nHALFILE = core.hal\n\
[TRAJ]\nCOORDINATES = X Y Z\nLINEAR_UNITS = mm\nANGULAR_UNITS = degree\nDEFAULT_LINEAR_VELOCITY = 100\nMAX_LINEAR_VELOCITY = 200\n\
[KINS]\nKINEMATICS = trivkins\nJOINTS = 3\n"
    );
    for a in ["X", "Y", "Z"] {
        s.push_str(&format!(
            "[AXIS_{a}]\nMAX_VELOCITY = 200\nMAX_ACCELERATION = 2000\nMIN_LIMIT = -200\nMAX_LIMIT = 700\n"
        ));
    }
    for (j, extra) in cfg.joint_extra.iter().enumerate() {
        s.push_str(&format!(
            "[JOINT_{j}]\nTYPE = LINEAR\nHOME = 0\nMAX_VELOCITY = 200\nMAX_ACCELERATION = 2000\n\
MIN_LIMIT = -200\nMAX_LIMIT = 700\nFERROR = 10\nMIN_FERROR = 10\nHOME_SEARCH_VEL = 0\n\
HOME_LATCH_VEL = 0\nHOME_SEQUENCE = 0\n"
        ));
        for l in extra {
            s.push_str(l);
            s.push('\n');
        }
    }
    s
}

fn is_root() -> bool {
    let out = Command::new("id").arg("-u").output().expect("id -u");
    String::from_utf8_lossy(&out.stdout).trim() == "0"
}

/// Runs LinuxCNC in `dir` (created, world-writable) with the MDI lines; returns per line the
/// pin values in `cfg.pins` order.
pub(crate) fn run_mdi(dir: &Path, cfg: &Config, mdi: &[String]) -> Vec<(String, Vec<f64>)> {
    super::require("linuxcnc");
    super::require("halcmd");
    assert!(
        Path::new("/usr/bin/python3").is_file(),
        "/usr/bin/python3 (Debian's, with the linuxcnc module) is needed"
    );
    std::fs::create_dir_all(dir.join("home")).unwrap();
    let nml = std::fs::read_to_string("/usr/share/linuxcnc/linuxcnc.nml").unwrap_or_else(|e| {
        panic!(
            "/usr/share/linuxcnc/linuxcnc.nml: {e}. {}",
            super::INSTALL_HINT
        )
    });
    // Without TCP=5005 linuxcncsvr serves only local shared memory: no listening socket.
    std::fs::write(dir.join("loopback.nml"), nml.replace(" TCP=5005", "")).unwrap();
    std::fs::write(dir.join("display.py"), DISPLAY_PY).unwrap();
    std::fs::write(dir.join("core.hal"), CORE_HAL).unwrap();
    std::fs::write(dir.join("tool.tbl"), "").unwrap();
    std::fs::write(dir.join("pins.txt"), cfg.pins.join("\n")).unwrap();
    std::fs::write(dir.join("mdi.txt"), mdi.join("\n")).unwrap();
    let ini_path: PathBuf = dir.join("test.ini");
    std::fs::write(&ini_path, ini(dir, cfg)).unwrap();
    Command::new("chmod")
        .args(["-R", "a+rwX"])
        .arg(dir)
        .status()
        .unwrap();
    Command::new("chmod")
        .arg("755")
        .arg(dir.join("display.py"))
        .status()
        .unwrap();
    let mut cmd = if is_root() {
        let mut c = Command::new("setpriv");
        c.args(["--reuid=65534", "--regid=65534", "--clear-groups", "env"]);
        c.arg(format!("HOME={}", dir.join("home").display()));
        c.arg("linuxcnc");
        c
    } else {
        Command::new("linuxcnc")
    };
    let out = cmd
        .arg(&ini_path)
        .current_dir(dir)
        .output()
        .expect("start linuxcnc");
    let result = std::fs::read_to_string(dir.join("result.txt")).unwrap_or_default();
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        result.lines().last() == Some("DONE"),
        "LinuxCNC run did not complete ({}):\n{result}\n{log}",
        out.status
    );
    result
        .lines()
        .filter(|l| *l != "DONE")
        .map(|l| {
            let mut f = l.split('\t');
            let line = f.next().unwrap().to_string();
            (line, f.map(|v| v.parse().unwrap()).collect())
        })
        .collect()
}
