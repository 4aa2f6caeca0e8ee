//! Tests of the SD session log on an emulated card, formatted and read back by an
//! independent FAT implementation (`fatfs`).

use super::*;
use crate::Vec3;
use crate::session_log::{Detail, LogError, Recorder};
extern crate std;
use std::io::{Cursor, Read};
use std::string::String;
use std::vec;
use std::vec::Vec;

/// First block of the card's single partition (1 MiB, as SD cards come formatted).
const PART_START: usize = 2048;

/// A card image of `mib` MiB: an MBR with one partition, formatted `fat`.
fn formatted(mib: usize, fat: fatfs::FatType) -> Vec<u8> {
    let mut img = vec![0u8; mib << 20];
    let blocks = u32::try_from(img.len() / 512 - PART_START).unwrap();
    let entry = &mut img[446..462];
    entry[4] = if fat == fatfs::FatType::Fat32 {
        0x0C
    } else {
        0x0E
    };
    entry[8..12].copy_from_slice(&u32::try_from(PART_START).unwrap().to_le_bytes());
    entry[12..16].copy_from_slice(&blocks.to_le_bytes());
    img[510] = 0x55;
    img[511] = 0xAA;
    fatfs::format_volume(
        Cursor::new(&mut img[PART_START * 512..]),
        // Small clusters: the smallest images that hold a FAT16 (4085 clusters) or a
        // FAT32 (65 525 clusters) volume, and many cluster allocations per session.
        fatfs::FormatVolumeOptions::new()
            .fat_type(fat)
            .bytes_per_cluster(512),
    )
    .unwrap();
    img
}

/// The contents of `name` in the image's root directory, read by `fatfs`.
fn read_back(img: &mut [u8], name: &str) -> Option<Vec<u8>> {
    let fs = fatfs::FileSystem::new(
        Cursor::new(&mut img[PART_START * 512..]),
        fatfs::FsOptions::new(),
    )
    .unwrap();
    let mut file = fs.root_dir().open_file(name).ok()?;
    let mut out = Vec::new();
    file.read_to_end(&mut out).unwrap();
    Some(out)
}

#[test]
fn names_round_trip_and_others_are_ignored() {
    assert_eq!(&file_name(42), b"SESS0042.LOG");
    assert_eq!(&file_name(MAX_SESSION), b"SESS9999.LOG");
    for n in [1, 42, 9999] {
        let name = file_name(n);
        let short = ShortFileName::create_from_str(core::str::from_utf8(&name).unwrap()).unwrap();
        assert_eq!(session_number(&short), Some(n));
    }
    for other in [
        "SESS0042.TXT",
        "SES00042.LOG",
        "SESSX042.LOG",
        "README.LOG",
        "SESS42.LOG",
    ] {
        let short = ShortFileName::create_from_str(other).unwrap();
        assert_eq!(session_number(&short), None, "{other}");
    }
}

#[test]
fn blank_card_is_refused_and_handed_back() {
    let mut img = vec![0u8; 1 << 20];
    let card = RamCard::new(&mut img);
    let Err((e, card)) = SdLog::open(card, 0) else {
        panic!("a blank card mounted");
    };
    assert_eq!(e, SdError::Volume);
    assert_eq!(card.writes(), 0);
}

#[test]
fn each_session_gets_the_next_number() {
    let mut img = formatted(4, fatfs::FatType::Fat16);
    // A session file left by an earlier firmware and an unrelated file.
    {
        let fs = fatfs::FileSystem::new(
            Cursor::new(&mut img[PART_START * 512..]),
            fatfs::FsOptions::new(),
        )
        .unwrap();
        fs.root_dir().create_file("SESS0041.LOG").unwrap();
        fs.root_dir().create_file("NOTES.TXT").unwrap();
    }
    for expect in [42, 43] {
        let card = RamCard::new(&mut img);
        let Ok(mut log) = SdLog::open(card, 0) else {
            panic!("mount failed");
        };
        assert_eq!(log.number(), expect);
        log.write(b"{\"type\":\"header\"}\n").unwrap();
        let (_, r) = log.into_card(10);
        r.unwrap();
    }
    assert_eq!(
        read_back(&mut img, "SESS0043.LOG").unwrap(),
        b"{\"type\":\"header\"}\n"
    );
}

/// Writes a session of `seconds` through a recorder into the SD log: IMU records at
/// 100 Hz, a pulse every second (written 0.3 s after its centre, as the front end
/// does), an event now and then; `poll` between records, as the board does.
/// Returns the text given to the log, each record's (end offset, time ms, blocks
/// written by then) and each flush's (blocks written by then, bytes flushed).
struct Session {
    text: Vec<u8>,
    records: Vec<(usize, u64, u64)>,
    flushes: Vec<(u64, u64)>,
}

fn run_session(card: RamCard<'_>, seconds: u64) -> Session {
    run_until_power_off(card, seconds, false)
}

/// `run_session`, where `cut` says the card's supply may go: the session then stops at
/// the first error (the board is dead).
fn run_until_power_off(card: RamCard<'_>, seconds: u64, cut: bool) -> Session {
    let log = match SdLog::open(card, 0) {
        Ok(log) => log,
        // Power lost while the file was being created.
        Err(_) if cut => {
            return Session {
                text: Vec::new(),
                records: Vec::new(),
                flushes: Vec::new(),
            };
        }
        Err((e, _)) => panic!("mount failed: {e}"),
    };
    let mut rec = Recorder::new(log);
    let mut records = Vec::new();
    let mut flushes = Vec::new();
    let earth = Vec3::new(21.0, 0.0, -42.0);
    for tick in 0..seconds * 100 {
        let now_ms = tick * 10;
        let t = now_ms as f64 / 1000.0;
        let before = rec.stats().written;
        let x = tick as f32 * 1e-3;
        let r = if tick == 0 {
            rec.header(100.0, &earth, true)
        } else {
            Ok(())
        }
        .and_then(|()| {
            rec.imu(
                t,
                &Vec3::new(x, -0.2, 9.8),
                &Vec3::new(0.01, x, 0.0),
                Some(&earth),
            )
        })
        .and_then(|()| match tick % 100 == 30 && tick > 100 {
            true => rec.pulse(t - 0.3, &Vec3::new(1.5e-6, -x * 1e-6, 3e-7), None),
            false => Ok(()),
        })
        .and_then(|()| match tick % 250 == 7 {
            true => rec.event(t, "read_error", Some("imu"), &[("count", Detail::Int(1))]),
            false => Ok(()),
        });
        let bytes = rec.writer().stats().bytes;
        let log = rec.writer();
        let flushed = log.poll(now_ms);
        if cut && (r.is_err() || flushed.is_err()) {
            break;
        }
        r.unwrap();
        assert!(rec.stats().written > before);
        let log = rec.writer();
        let flushed = flushed.unwrap();
        records.push((usize::try_from(bytes).unwrap(), now_ms, log_writes(log)));
        if flushed {
            flushes.push((log_writes(log), log.stats().flushed_bytes));
        }
    }
    // The text the log was given, rebuilt by a recorder writing to memory (the same
    // records, so the same bytes).
    Session {
        text: session_text(seconds),
        records,
        flushes,
    }
}

fn log_writes(log: &mut SdLog<RamCard<'_>>) -> u64 {
    log.card(|card| card.writes())
}

/// The same session as `run_session`, written to memory.
fn session_text(seconds: u64) -> Vec<u8> {
    let mut rec = Recorder::new(String::new());
    let earth = Vec3::new(21.0, 0.0, -42.0);
    for tick in 0..seconds * 100 {
        let t = (tick * 10) as f64 / 1000.0;
        if tick == 0 {
            rec.header(100.0, &earth, true).unwrap();
        }
        let x = tick as f32 * 1e-3;
        rec.imu(
            t,
            &Vec3::new(x, -0.2, 9.8),
            &Vec3::new(0.01, x, 0.0),
            Some(&earth),
        )
        .unwrap();
        if tick % 100 == 30 && tick > 100 {
            rec.pulse(t - 0.3, &Vec3::new(1.5e-6, -x * 1e-6, 3e-7), None)
                .unwrap();
        }
        if tick % 250 == 7 {
            rec.event(t, "read_error", Some("imu"), &[("count", Detail::Int(1))])
                .unwrap();
        }
    }
    rec.into_writer().into_bytes()
}

/// Cuts the power at every block write of a session (FAT16 and FAT32) and checks what a
/// remount finds: a prefix of the session, ending on a whole line, holding at least
/// everything flushed before the cut, so every record more than one second older than
/// the cut.
#[test]
fn power_loss_keeps_everything_flushed() {
    for (fat, mib, seconds, step) in [
        (fatfs::FatType::Fat16, 4, 4, 1),
        (fatfs::FatType::Fat32, 34, 3, 10),
    ] {
        let blank = formatted(mib, fat);
        let mut img = blank.clone();
        let full = run_session(RamCard::new(&mut img), seconds);
        // Without a cut, after the last flush, the file is the session up to that flush.
        let (_, flushed) = *full.flushes.last().unwrap();
        let got = read_back(&mut img, "SESS0001.LOG").unwrap();
        assert_eq!(got.len() as u64, flushed);
        assert!(full.flushes.len() as u64 >= seconds * 1000 / FLUSH_INTERVAL_MS - 1);
        let total_writes = full.records.last().unwrap().2;
        let mut cuts = 0;
        for cut in (0..=total_writes).step_by(step) {
            img.copy_from_slice(&blank);
            let card = RamCard::new(&mut img);
            card.power_off_at(cut);
            let _ = run_until_power_off(card, seconds, true);
            // Before the first flush the file may not exist yet (or be empty).
            let got = read_back(&mut img, "SESS0001.LOG").unwrap_or_default();
            assert!(
                full.text.starts_with(&got),
                "{fat:?} cut at write {cut}: not a prefix of the session"
            );
            assert!(
                got.is_empty() || got.ends_with(b"\n"),
                "cut {cut}: torn line"
            );
            let kept = full
                .flushes
                .iter()
                .filter(|(w, _)| *w <= cut)
                .map(|(_, b)| *b)
                .max()
                .unwrap_or(0);
            assert!(got.len() as u64 >= kept, "cut {cut}: flushed bytes lost");
            // The instant of the cut: the first record whose writes reached it.
            if let Some(&(_, cut_ms, _)) = full.records.iter().find(|r| r.2 > cut) {
                for &(end, t_ms, _) in &full.records {
                    if t_ms + 1000 <= cut_ms {
                        assert!(got.len() >= end, "cut {cut} at {cut_ms} ms lost {t_ms} ms");
                    }
                }
            }
            cuts += 1;
        }
        std::eprintln!("{fat:?}: {total_writes} block writes, {cuts} cuts");
        assert!(cuts > 30, "{fat:?}: only {cuts} cuts tried");
    }
}

#[test]
fn card_errors_stop_the_log_and_are_counted() {
    let mut img = formatted(4, fatfs::FatType::Fat16);
    let card = RamCard::new(&mut img);
    card.fail_at(5);
    let Ok(log) = SdLog::open(card, 0) else {
        panic!("mount failed");
    };
    let mut rec = Recorder::new(log);
    rec.header(100.0, &Vec3::new(21.0, 0.0, -42.0), true)
        .unwrap();
    let mut failed_at = None;
    for tick in 0..500u64 {
        let r = rec.imu(tick as f64 * 0.01, &Vec3::zeros(), &Vec3::zeros(), None);
        let p = rec.writer().poll(tick * 10);
        if (r.is_err() || p.is_err()) && failed_at.is_none() {
            failed_at = Some(tick);
        }
        if failed_at.is_some() {
            assert!(rec.writer().failure().is_some());
        }
    }
    assert!(failed_at.is_some(), "the card error went unnoticed");
    let stats = rec.writer().stats();
    assert!(stats.errors >= 1);
    assert!(stats.lost_bytes > 0);
    // What was not flushed when the card failed is counted as lost.
    assert!(stats.flushed_bytes <= stats.bytes);
    assert!(stats.lost_bytes >= stats.bytes - stats.flushed_bytes);
    // Every record after the failure is counted by the recorder as failed.
    assert!(rec.stats().failed > 0);
    assert_eq!(
        rec.imu(9.0, &Vec3::zeros(), &Vec3::zeros(), None),
        Err(LogError::Write)
    );
    // The first error stays the log's state (a device error while a cluster is allocated
    // comes out of embedded-sdmmc as "disk full").
    let first = rec.writer().failure();
    assert!(
        matches!(first, Some(SdError::Card | SdError::Full)),
        "{first:?}"
    );
    assert_eq!(rec.writer().poll(10_000).err(), first);
}

#[test]
fn the_sink_reports_its_state_and_fails_only_with_a_failed_card() {
    use core::fmt::Write;
    let mut none: SdSink<RamCard<'_>> = SdSink::new(None);
    assert_eq!(none.state(), SdState::NoCard);
    assert_eq!(none.state().fault_label(), Some("NO SD"));
    none.write_str("taken, nowhere to go\n").unwrap();
    assert_eq!(none.poll(10_000), None);

    let mut blank = vec![0u8; 1 << 20];
    let refused = SdLog::open(RamCard::new(&mut blank), 0).map_err(|(e, _)| e);
    let mut bad = SdSink::new(Some(refused));
    assert_eq!(bad.state(), SdState::Failed(SdError::Volume));
    assert!(bad.write_str("x").is_err());

    let mut img = formatted(4, fatfs::FatType::Fat16);
    let card = RamCard::new(&mut img);
    card.fail_at(3);
    let mut ok = SdSink::new(Some(SdLog::open(card, 0).map_err(|(e, _)| e)));
    assert_eq!(ok.state(), SdState::Logging(1));
    assert_eq!(ok.state().fault_label(), None);
    let mut changed = Vec::new();
    for tick in 0..200u64 {
        let _ = ok.write_str("{\"type\":\"imu\",\"t\":0}\n");
        if let Some(s) = ok.poll(tick * 10) {
            changed.push(s);
        }
    }
    // The failure is reported once, then kept.
    assert_eq!(changed.len(), 1, "{changed:?}");
    assert!(matches!(changed[0], SdState::Failed(_)));
    assert!(ok.write_str("x").is_err());
    assert!(ok.stats().unwrap().lost_bytes > 0);
}

/// Lines of a session file (each must be whole).
fn lines_of(bytes: &[u8]) -> Vec<String> {
    let text = String::from_utf8(bytes.to_vec()).unwrap();
    assert!(text.is_empty() || text.ends_with('\n'), "a torn last line");
    text.lines().map(String::from).collect()
}

#[test]
fn a_failed_card_is_remounted_into_a_new_file_that_starts_with_a_header() {
    use crate::board::board_log::BoardLog;
    let mut img = formatted(4, fatfs::FatType::Fat16);
    let (mut states, mut fail_ms, mut repair_ms) = (Vec::new(), None, None);
    {
        let card = RamCard::new(&mut img);
        let sink = SdSink::new(Some(SdLog::open(card, 0).map_err(|(e, _)| e)));
        let mut log: BoardLog<RamCard<'_>, String> = BoardLog::new(sink, None);
        log.header(100.0, &Vec3::new(21.0, 0.0, -42.0), true);
        for tick in 0..3000u64 {
            let now = tick * 10;
            let t = now as f64 / 1000.0;
            if tick == 300 {
                // The card stops answering from its next block write.
                log.sd().card(|c| c.fail_at(c.writes()));
            }
            if tick == 1200 {
                // Reseated (or the glitch passed): the next remount gets it back.
                assert!(log.sd().log.is_none(), "the failed log was closed");
                if let Some(c) = &log.sd().card {
                    c.repair();
                }
                repair_ms = Some(now);
            }
            log.imu(t, &Vec3::zeros(), &Vec3::zeros(), None);
            if let (Some(s), _) = log.tick(t, now) {
                if matches!(s, SdState::Failed(_)) && fail_ms.is_none() {
                    fail_ms = Some(now);
                }
                states.push((now, s));
            }
        }
        assert_eq!(log.sd().remounts(), 1);
        assert_eq!(log.sd_state(), SdState::Logging(2));
    }
    let (fail_ms, repair_ms) = (fail_ms.unwrap(), repair_ms.unwrap());
    // Failed within a flush interval of the card's failure, remounted at the first try
    // after the repair (tries every 5 s from the failure on).
    assert!(
        (3000..=3000 + FLUSH_INTERVAL_MS + 10).contains(&fail_ms),
        "{states:?}"
    );
    let remounted = states
        .iter()
        .find(|(_, s)| *s == SdState::Logging(2))
        .map(|(t, _)| *t)
        .unwrap();
    assert!(
        remounted >= repair_ms && remounted < repair_ms + REMOUNT_INTERVAL_MS,
        "{states:?}"
    );
    assert_eq!((remounted - fail_ms) % REMOUNT_INTERVAL_MS, 0, "{states:?}");

    let first = lines_of(&read_back(&mut img, "SESS0001.LOG").unwrap());
    let second = lines_of(&read_back(&mut img, "SESS0002.LOG").unwrap());
    assert!(first[0].starts_with("{\"type\":\"header\""), "{}", first[0]);
    // The first file holds what was flushed before the failure (≥ 2.5 s of records).
    assert!(first.len() > 250, "{} lines", first.len());
    // The second starts a new segment, says why, and goes on to the end (the last
    // flush is at most 0.5 s old).
    assert!(
        second[0].starts_with("{\"type\":\"header\""),
        "{}",
        second[0]
    );
    assert!(
        second[1].contains("\"why\":\"sd_remount\",\"file\":2"),
        "{}",
        second[1]
    );
    let t = |l: &str| -> f64 {
        let at = l.find("\"t\":").unwrap() + 4;
        l[at..].split(',').next().unwrap().parse().unwrap()
    };
    let imu: Vec<f64> = second
        .iter()
        .filter(|l| l.contains("\"imu\""))
        .map(|l| t(l))
        .collect();
    assert!(
        imu.first()
            .is_some_and(|&t0| t0 * 1000.0 >= remounted as f64 - 10.0)
    );
    assert!(imu.last().is_some_and(|&t1| t1 >= 29.4), "{:?}", imu.last());
    // No record is cut: every line of both files is whole JSON with its seq.
    for l in first.iter().chain(&second) {
        assert!(
            l.starts_with('{') && l.ends_with('}') && l.contains("\"seq\":"),
            "{l}"
        );
    }
}

#[test]
fn a_card_that_stays_dead_is_tried_a_few_times_then_left_alone() {
    use core::fmt::Write;
    let mut img = formatted(4, fatfs::FatType::Fat16);
    let card = RamCard::new(&mut img);
    card.fail_at(2);
    let mut sink = SdSink::new(Some(SdLog::open(card, 0).map_err(|(e, _)| e)));
    let mut tries = 0;
    for tick in 0..12_000u64 {
        let _ = sink.write_str("{\"type\":\"imu\",\"t\":0}\n");
        let before = sink.tries_left;
        sink.poll(tick * 10);
        tries += usize::from(sink.tries_left < before);
    }
    assert_eq!(tries, usize::from(REMOUNT_TRIES));
    assert!(matches!(sink.state(), SdState::Failed(_)));
    assert_eq!((sink.retry_at_ms, sink.remounts()), (None, 0));
    assert!(sink.card.is_some(), "the card is kept");
}

#[test]
fn a_card_refused_at_boot_is_mounted_once_it_answers() {
    let mut img = formatted(4, fatfs::FatType::Fat16);
    let card = RamCard::new(&mut img);
    card.fail_at(0);
    let Err((e, card)) = SdLog::open(card, 0) else {
        panic!("mounted a failing card");
    };
    assert_eq!(e, SdError::Card);
    let mut sink = SdSink::mount_failed(e, card, 0);
    assert_eq!(sink.poll(REMOUNT_INTERVAL_MS - 1), None);
    if let Some(c) = &sink.card {
        c.repair();
    }
    assert_eq!(sink.poll(REMOUNT_INTERVAL_MS), Some(SdState::Logging(1)));
}
