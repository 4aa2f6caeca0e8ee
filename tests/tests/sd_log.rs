//! SD-card session log (issue 21): a seeded search recorded by the board's writer
//! (`firmware::session_log::Recorder`) into the SD log (`firmware::board::sd_log`) on an
//! emulated card whose power is cut in the middle of the search. After a remount (as
//! the board's library reads the card) the session file holds every record up to the
//! last flush, so every record more than one second before the cut, with `seq` unbroken,
//! and it replays through `hal-sim`'s streaming reader and the firmware's pipeline.
// Test code: a failed unwrap or a panic is a failed test, the right report.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
use embedded_sdmmc::{Mode, VolumeIdx, VolumeManager};
use firmware::Vec3;
use firmware::board::sd_log::{FixedTime, RamCard, SdLog};
use firmware::session_log::Recorder;
use hal_sim::io::receiver_config::ReceiverConfig;
use hal_sim::io::replay::replay_clean;
use hal_sim::io::session::Record;
use hal_sim::world::scenario::{Preset, ScenarioConfig, simulate};
use std::io::Cursor;

/// First block of the card's partition.
const PART_START: usize = 2048;

/// A 40 MiB card: an MBR with one FAT32 partition (the format of SDHC cards).
fn fat32_card() -> Vec<u8> {
    let mut img = vec![0u8; 40 << 20];
    let blocks = u32::try_from(img.len() / 512 - PART_START).unwrap();
    img[446 + 4] = 0x0C;
    img[446 + 8..446 + 12].copy_from_slice(&u32::try_from(PART_START).unwrap().to_le_bytes());
    img[446 + 12..446 + 16].copy_from_slice(&blocks.to_le_bytes());
    img[510] = 0x55;
    img[511] = 0xAA;
    fatfs::format_volume(
        Cursor::new(&mut img[PART_START * 512..]),
        fatfs::FormatVolumeOptions::new()
            .fat_type(fatfs::FatType::Fat32)
            .bytes_per_cluster(512),
    )
    .unwrap();
    img
}

fn v(a: &[f64; 3]) -> Vec3 {
    Vec3::new(a[0] as f32, a[1] as f32, a[2] as f32)
}

/// Reads session file `name` as the board's library does after a power-up.
fn remount_and_read(img: &mut [u8], name: &str) -> Vec<u8> {
    let mgr: VolumeManager<_, _, 1, 1, 1> =
        VolumeManager::new_with_limits(RamCard::new(img), FixedTime, 0);
    let volume = mgr.open_volume(VolumeIdx(0)).unwrap();
    let root = volume.open_root_dir().unwrap();
    let file = root.open_file_in_dir(name, Mode::ReadOnly).unwrap();
    let mut out = Vec::new();
    let mut buf = [0u8; 512];
    while !file.is_eof() {
        let n = file.read(&mut buf).unwrap();
        out.extend_from_slice(&buf[..n]);
    }
    out
}

#[test]
fn power_cut_loses_at_most_the_last_second_and_the_log_replays() {
    let sim = simulate(&ScenarioConfig::new(Preset::Paper, 5));
    let h = &sim.session.header;
    let cut_s = 20.0;
    let mut img = fat32_card();
    let card = RamCard::new(&mut img);
    let Ok(log) = SdLog::open(card, 0) else {
        panic!("the card did not mount");
    };
    assert_eq!(log.number(), 1);
    let mut rec = Recorder::new(log);
    rec.header(
        h.imu_hz as f32,
        &v(&h.earth_field_ut.unwrap()),
        h.sign_ambiguous,
    )
    .unwrap();
    // Times of the records given to the log until it failed.
    let mut written: Vec<f64> = Vec::new();
    for r in &sim.session.records {
        let t = r.t();
        if t >= cut_s && written.last().is_some_and(|&l| l < cut_s) {
            // The supply goes: nothing written from now on reaches the card.
            rec.writer().card(|c| c.power_off_at(c.writes()));
        }
        let ok = match r {
            Record::Imu(x) => rec.imu(x.t, &v(&x.acc), &v(&x.gyr), x.mag.as_ref().map(v).as_ref()),
            Record::Pulse(x) => rec.pulse(x.t, &v(&x.h), None),
            Record::Truth(_) => continue,
        };
        let polled = rec.writer().poll((t * 1000.0) as u64);
        if ok.is_err() || polled.is_err() {
            break; // the board is dead
        }
        written.push(t);
    }
    let last_t = sim.session.records.last().map_or(0.0, Record::t);
    assert!(
        last_t > cut_s + 2.0,
        "the search ended at {last_t} s, before the cut"
    );
    drop(rec);

    let text = remount_and_read(&mut img, "SESS0001.LOG");
    assert!(text.ends_with(b"\n"), "torn last line");
    let summary = replay_clean(&text, &ReceiverConfig::default()).unwrap();
    let read = summary.read;
    assert_eq!((read.segments, read.malformed, read.seq_gaps), (1, 0, 0));
    let kept = (read.imu + read.pulses) as usize;
    // Every record more than one second before the cut is there, nothing after it.
    let before_cut = written.iter().filter(|&&t| t < cut_s).count();
    let a_second_before = written.iter().filter(|&&t| t <= cut_s - 1.0).count();
    assert!(
        (a_second_before..=before_cut).contains(&kept),
        "{kept} records kept, {a_second_before} needed, {before_cut} written before the cut"
    );
    // One replay line per pulse kept.
    assert_eq!(summary.lines, read.pulses);
    assert!(read.pulses >= 10, "{} pulses", read.pulses);
    eprintln!(
        "cut at {cut_s} s: {kept} of {before_cut} records kept ({} needed), {} pulses replayed",
        a_second_before, read.pulses
    );
}
