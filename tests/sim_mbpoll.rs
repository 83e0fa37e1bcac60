//! An independent Modbus master (Debian's `mbpoll`, libmodbus) talks to `rigscript sim c29u`
//! over a real pty: reads DO and DI coils, counters as input and holding registers, and writes a
//! coil and multiple coils.

use crate::common::{require_tool, run, stderr, stdout, SimProcess};

/// Runs mbpoll once against `path` for slave 1 and returns the `[ref]: value` pairs it printed.
fn mbpoll(path: &str, args: &[&str]) -> Vec<(u16, i64)> {
    let mut all = vec![
        "-m", "rtu", "-a", "1", "-b", "9600", "-P", "none", "-0", "-1", "-o", "1",
    ];
    all.extend_from_slice(args);
    all.push(path);
    let out = run("mbpoll", &all);
    let text = stdout(&out);
    assert!(
        out.status.success(),
        "mbpoll {args:?} failed: {text}{}",
        stderr(&out)
    );
    text.lines()
        .filter_map(|line| {
            let (reference, value) = line.trim().strip_prefix('[')?.split_once("]:")?;
            Some((reference.trim().parse().ok()?, value.trim().parse().ok()?))
        })
        .collect()
}

fn mbpoll_write(path: &str, args: &[&str], values: &[&str]) {
    let mut all = vec![
        "-m", "rtu", "-a", "1", "-b", "9600", "-P", "none", "-0", "-1", "-o", "1",
    ];
    all.extend_from_slice(args);
    all.push(path);
    all.extend_from_slice(values);
    let out = run("mbpoll", &all);
    assert!(
        out.status.success(),
        "mbpoll write {args:?} {values:?} failed: {}{}",
        stdout(&out),
        stderr(&out)
    );
}

#[test]
#[ignore = "needs mbpoll (tier 2: .ci/run installs it)"]
fn mbpoll_reads_and_writes_the_simulated_module() {
    require_tool("mbpoll", "mbpoll");
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1", "--di", "0x05"]);
    let path = sim.path.clone();

    // DO at coil 0x00: all off at power on (factory power-on value 0).
    let coils = mbpoll(&path, &["-t", "0", "-r", "0", "-c", "8"]);
    assert_eq!(coils, (0..8).map(|i| (i, 0)).collect::<Vec<_>>());

    // DI at coil 0x20, active-low on the wire: DI0 and DI2 energized read as 0.
    let di = mbpoll(&path, &["-t", "0", "-r", "32", "-c", "8"]);
    let expected: Vec<(u16, i64)> = (0..8u16)
        .map(|i| (32 + i, if i == 0 || i == 2 { 0 } else { 1 }))
        .collect();
    assert_eq!(di, expected);

    // Counters as input registers (04) and holding registers (03).
    assert_eq!(sim.control("pulse 3 5"), "ok");
    assert_eq!(sim.control("pulse 7 65537"), "ok");
    let input_regs = mbpoll(&path, &["-t", "3", "-r", "0", "-c", "8"]);
    let holding = mbpoll(&path, &["-t", "4", "-r", "0", "-c", "8"]);
    // Inputs energized at power on count nothing; pulses count rising edges; 65537 wrap to 1.
    let expected: Vec<(u16, i64)> = vec![
        (0, 0),
        (1, 0),
        (2, 0),
        (3, 5),
        (4, 0),
        (5, 0),
        (6, 0),
        (7, 1),
    ];
    assert_eq!(input_regs, expected);
    assert_eq!(holding, expected);

    // Write one coil (05): DO3 on.
    mbpoll_write(&path, &["-t", "0", "-r", "3"], &["1"]);
    assert_eq!(sim.state()["do"], 0x08);
    let coils = mbpoll(&path, &["-t", "0", "-r", "0", "-c", "8"]);
    assert_eq!(coils.get(3), Some(&(3, 1)));

    // Write multiple coils (0F): DO = 0b0010_0101.
    mbpoll_write(
        &path,
        &["-t", "0", "-r", "0"],
        &["1", "0", "1", "0", "0", "1", "0", "0"],
    );
    assert_eq!(sim.state()["do"], 0x25);

    // A slave that is not on the line: silence, so the master times out.
    let out = run(
        "mbpoll",
        &[
            "-m", "rtu", "-a", "7", "-b", "9600", "-P", "none", "-0", "-1", "-o", "0.3", "-t", "0",
            "-r", "0", "-c", "8", &path,
        ],
    );
    let all = format!("{}{}", stdout(&out), stderr(&out));
    assert!(
        all.contains("timed out"),
        "an absent ID gets no answer: {all}"
    );

    assert_eq!(sim.terminate(), Some(0));
}
