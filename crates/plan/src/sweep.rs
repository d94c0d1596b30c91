//! A sweep: one study over several scenes and/or sensor catalogs, or a directory of studies,
//! run as one set of stages with one comparison across them (`hilo_study::compare`).
//!
//! Two ways to write one:
//! - a study file with `scenes = [...]` and/or `catalogs = [...]` instead of `scene` /
//!   `catalog`, and/or `weathers = { clear = {}, fog = { fog_visibility_m = 60 } }` instead of
//!   `[dataset.weather]`: every (scene, catalog, weather) is a study, named after the files'
//!   stems and the weather's name, joined by `-` (`<scene>-<catalog>-<weather>`, each part
//!   present when its list is given);
//! - a directory: every `*.toml` directly in it is a study, named after its stem.
//!
//! Either file may build on another study with `extends = "../study.toml"`
//! ([`crate::study::read_study_text`]): a sweep of the default study over a site library is
//! `extends` and a `scenes` list.
//!
//! Each study of a sweep (a *shard*) has its own folder `<out>/<name>/`, its own plan, hashes
//! and report, exactly as if it were run alone; `<out>/sweep.json` records the shards and
//! `<out>/comparison.md` / `comparison.json` put them side by side.

use crate::error::{Result, StudyError};
use crate::plan::Plan;
use crate::study::{Study, StudyFile, slug};
use hilo_core::fs::{limit, read_json, write_json};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub use crate::study::LIST_KEYS;

/// One study of a sweep.
#[derive(Clone, Debug)]
pub struct Shard {
    /// File-name-safe, unique in the sweep: the shard's folder under the sweep's.
    pub name: String,
    pub study: Study,
}

/// Several studies compared in one report.
#[derive(Clone, Debug)]
pub struct Sweep {
    /// The study file or directory it came from.
    pub source: String,
    pub shards: Vec<Shard>,
}

/// What a path names: one study, or a sweep of them.
#[derive(Clone, Debug)]
#[allow(clippy::large_enum_variant)]
pub enum Loaded {
    Study(Study),
    Sweep(Sweep),
}

/// Loads a study file, a study file listing several scenes or catalogs, or a directory of study
/// files.
pub fn load(path: &Path) -> Result<Loaded> {
    if path.is_dir() {
        return directory(path).map(Loaded::Sweep);
    }
    let text = crate::study::read_study_text(path)?;
    parse(&text, path.parent().unwrap_or(Path::new(".")), &path.display().to_string())
}

/// [`load`] of a study file's text whose relative paths resolve against `dir`.
pub fn parse(text: &str, dir: &Path, source: &str) -> Result<Loaded> {
    let bad =
        |m: String| StudyError::from(hilo_core::fs::FileError::Content { path: PathBuf::from(source), message: m });
    let mut table: toml::Table = toml::from_str(text).map_err(|e| bad(format!("invalid study: {e}")))?;
    crate::study::refuse_non_finite(&table, source)?;
    let mut lists = Vec::new();
    for key in LIST_KEYS {
        let single = key.trim_end_matches('s');
        let Some(v) = table.remove(key) else {
            lists.push(None);
            continue;
        };
        if table.contains_key(single) {
            return Err(bad(format!("give `{single}` or `{key}`, not both")));
        }
        let paths: Vec<PathBuf> =
            v.try_into().map_err(|e| bad(format!("`{key}` must be a list of file paths: {e}")))?;
        if paths.is_empty() {
            return Err(bad(format!("`{key}` = []: list at least one file, or leave it out")));
        }
        lists.push(Some(paths));
    }
    let weathers = match table.remove(crate::study::WEATHERS_KEY) {
        None => None,
        Some(v) => Some(weathers(v, &table, source)?),
    };
    if lists.iter().all(Option::is_none) && weathers.is_none() {
        return Study::parse(text, dir, source).map(Loaded::Study);
    }
    let base: StudyFile = toml::Value::Table(table).try_into().map_err(|e| bad(format!("invalid study: {e}")))?;
    let weathers: Vec<(Option<String>, hilo_sensor_models::Weather)> = match weathers {
        None => vec![(None, base.dataset.weather)],
        Some(w) => w.into_iter().map(|(n, w)| (Some(n), w)).collect(),
    };
    let axis =
        |list: &Option<Vec<PathBuf>>, default: &Option<PathBuf>| -> Result<Vec<(Option<String>, Option<PathBuf>)>> {
            match list {
                None => Ok(vec![(None, default.clone())]),
                Some(paths) => paths.iter().map(|p| Ok((Some(stem(p, source)?), Some(p.clone())))).collect(),
            }
        };
    let scenes = axis(&lists[0], &base.scene)?;
    let catalogs = axis(&lists[1], &base.catalog)?;
    let mut shards: Vec<Shard> = Vec::new();
    for (scene_name, scene) in &scenes {
        for (catalog_name, catalog) in &catalogs {
            for (weather_name, weather) in &weathers {
                let name = [scene_name, catalog_name, weather_name]
                    .into_iter()
                    .flatten()
                    .cloned()
                    .collect::<Vec<_>>()
                    .join("-");
                let mut file = StudyFile { scene: scene.clone(), catalog: catalog.clone(), ..base.clone() };
                file.dataset.weather = *weather;
                let mut study = Study::from_file(file, dir, source).map_err(|e| bad(format!("study {name:?}: {e}")))?;
                study.shard = Some(name.clone());
                push_unique(&mut shards, Shard { name, study }, source)?;
            }
        }
    }
    Ok(Loaded::Sweep(Sweep { source: source.to_owned(), shards }))
}

/// The named weather conditions of `weathers = { name = { rain_mm_h = …, fog_visibility_m = … } }`
/// (names as slugs, in name order), each checked; refused beside `[dataset.weather]`.
fn weathers(v: toml::Value, table: &toml::Table, source: &str) -> Result<Vec<(String, hilo_sensor_models::Weather)>> {
    let key = crate::study::WEATHERS_KEY;
    let bad = |field: String, value: &dyn std::fmt::Display, reason: String| {
        StudyError::setting(source, field, value, reason)
    };
    let t: toml::Table = v.try_into().map_err(|e| {
        bad(
            key.into(),
            &"(not a table)",
            format!("must be a table of named conditions, e.g. {key} = {{ clear = {{}}, fog = {{ fog_visibility_m = 60.0 }} }}: {e}"),
        )
    })?;
    if t.is_empty() {
        return Err(bad(key.into(), &"{}", "name at least one condition, or leave it out".into()));
    }
    if table.get("dataset").and_then(|d| d.get("weather")).is_some() {
        return Err(bad(key.into(), &"(given)", "give `dataset.weather` or this, not both".into()));
    }
    let mut out: Vec<(String, hilo_sensor_models::Weather)> = Vec::new();
    for (name, v) in t {
        let shown = v.to_string();
        let w: hilo_sensor_models::Weather =
            v.try_into().map_err(|e| bad(format!("{key}.{name}"), &shown, e.to_string()))?;
        w.check().map_err(|e| bad(format!("{key}.{name}.{}", e.field), &e.value, e.reason.to_owned()))?;
        let s = slug(&name);
        if s.is_empty() || out.iter().any(|(n, _)| *n == s) {
            return Err(bad(
                format!("{key}.{name}"),
                &shown,
                "give each condition a distinct name of letters or digits".into(),
            ));
        }
        out.push((s, w));
    }
    Ok(out)
}

/// Every `*.toml` directly in `dir` (sorted by name) as a study of one scene and catalog.
fn directory(dir: &Path) -> Result<Sweep> {
    let files = hilo_core::fs::files_with_extension(dir, "toml")?;
    if files.is_empty() {
        return Err(StudyError::folder(dir, "a directory of studies holds no *.toml file"));
    }
    let mut shards = Vec::new();
    for f in files {
        let abs = std::fs::canonicalize(&f).map_err(|e| hilo_core::fs::FileError::io(&f, e))?;
        let source = abs.display().to_string();
        let study = match load(&abs)? {
            Loaded::Study(s) => s,
            Loaded::Sweep(_) => {
                return Err(StudyError::from(hilo_core::fs::FileError::Content {
                    path: abs,
                    message: "lists several scenes or catalogs; a directory of studies holds studies of one scene and catalog each".into(),
                }));
            }
        };
        push_unique(&mut shards, Shard { name: stem(&f, &source)?, study }, &dir.display().to_string())?;
    }
    Ok(Sweep { source: dir.display().to_string(), shards })
}

/// A file's stem as a shard name.
fn stem(p: &Path, source: &str) -> Result<String> {
    let s = slug(&p.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default());
    if s.is_empty() {
        return Err(StudyError::from(hilo_core::fs::FileError::Content {
            path: PathBuf::from(source),
            message: format!("{}: no letters or digits in the file name to name its study by", p.display()),
        }));
    }
    Ok(s)
}

fn push_unique(shards: &mut Vec<Shard>, shard: Shard, source: &str) -> Result<()> {
    if let Some(other) = shards.iter().find(|s| s.name == shard.name) {
        return Err(StudyError::from(hilo_core::fs::FileError::Content {
            path: PathBuf::from(source),
            message: format!(
                "two studies would share the name {:?} ({} and {}): give the files different names",
                shard.name,
                describe(&other.study),
                describe(&shard.study)
            ),
        }));
    }
    shards.push(shard);
    Ok(())
}

/// The scene and catalog files of a study, for messages.
fn describe(s: &Study) -> String {
    let f = |p: &Option<PathBuf>| p.as_ref().map_or("the default".to_owned(), |p| p.display().to_string());
    format!("scene {}, catalog {} in {}", f(&s.file.scene), f(&s.file.catalog), s.source)
}

/// What a sweep's folder records (`sweep.json`): its shards, where each one's folder is and
/// which study it holds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SweepRecord {
    pub source: String,
    pub profile: String,
    pub shards: Vec<ShardRecord>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShardRecord {
    pub name: String,
    /// The shard's scene and catalog files (None: the embedded defaults).
    pub scene: Option<PathBuf>,
    pub catalog: Option<PathBuf>,
    /// The shard's plan fingerprint (as its folder's `study.json` records it).
    pub fingerprint: String,
}

impl SweepRecord {
    pub fn path(out: &Path) -> PathBuf {
        out.join("sweep.json")
    }

    /// Reads `<out>/sweep.json`.
    pub fn read(out: &Path) -> Result<SweepRecord> {
        let p = SweepRecord::path(out);
        if !p.exists() {
            return Err(StudyError::NotReady {
                path: out.to_path_buf(),
                what: "not a sweep folder (no sweep.json)".into(),
                remedy: format!("run `hilo study <sweep> --out {}` first", out.display()),
            });
        }
        Ok(read_json(&p, limit::TABLE)?)
    }
}

impl Sweep {
    /// Where shard `name`'s folder is.
    pub fn shard_out(out: &Path, name: &str) -> PathBuf {
        out.join(name)
    }

    /// Claims `out` for this sweep (the plans are its shards', in order, each with its folder
    /// under `out`) and every shard's folder for its study; refuses a folder holding anything
    /// else, or another sweep.
    pub fn claim_folder(&self, out: &Path, plans: &[Plan]) -> Result<()> {
        let record = SweepRecord {
            source: self.source.clone(),
            profile: plans.first().map(|p| p.profile.name.to_string()).unwrap_or_default(),
            shards: self
                .shards
                .iter()
                .zip(plans)
                .map(|(s, p)| ShardRecord {
                    name: s.name.clone(),
                    scene: s.study.file.scene.clone(),
                    catalog: s.study.file.catalog.clone(),
                    fingerprint: p.fingerprint.clone(),
                })
                .collect(),
        };
        let marker = SweepRecord::path(out);
        if marker.exists() {
            let old: SweepRecord = read_json(&marker, limit::TABLE)?;
            if old != record {
                return Err(StudyError::folder(
                    out,
                    format!(
                        "holds another sweep (its studies, their files or the profile differ from {}); choose another --out",
                        self.source
                    ),
                ));
            }
        } else {
            if out.exists() && std::fs::read_dir(out).map(|mut d| d.next().is_some()).unwrap_or(false) {
                return Err(StudyError::folder(out, "exists and is not a sweep folder; choose another --out"));
            }
            std::fs::create_dir_all(out).map_err(|e| hilo_core::fs::FileError::io(out, e))?;
            write_json(&marker, &record)?;
        }
        for (s, p) in self.shards.iter().zip(plans) {
            p.claim_folder(&s.study)?;
        }
        Ok(())
    }
}

/// `hilo study plan` on a sweep's folder `out`: each study's stages ([`Plan::status`]), then
/// the comparison, done or not. `default` gives the embedded study, as for [`reopen`].
pub fn status(out: &Path, registry: &hilo_detector::Registry, default: impl Fn() -> Result<Study>) -> Result<String> {
    let record = SweepRecord::read(out)?;
    let mut lines = Vec::new();
    for s in &record.shards {
        lines.push(format!("== study {}", s.name));
        lines.push(reopen(&Sweep::shard_out(out, &s.name), registry, &default)?.1.status());
    }
    let comparison = out.join("comparison.json");
    let done = if comparison.exists() { "done" } else { "to do" };
    lines.push(format!("compare                   {done}  {}", comparison.display()));
    Ok(lines.join("\n"))
}

/// The study and plan a study folder records, checked against the study file as it is now: the
/// same file (or the same study of a sweep's file) must still give the recorded fingerprint.
/// `default` gives the embedded default study, for a folder made from it.
pub fn reopen(
    out: &Path,
    registry: &hilo_detector::Registry,
    default: impl FnOnce() -> Result<Study>,
) -> Result<(Study, Plan)> {
    let record = crate::plan::FolderRecord::read(out)?;
    let marker = out.join("study.json");
    let refuse = |why: String| Err(StudyError::folder(&marker, format!("{why}; run it into a new folder")));
    let study = if record.study.starts_with("<embedded>") {
        default()?
    } else {
        match (load(Path::new(&record.study))?, &record.shard) {
            (Loaded::Study(s), None) => s,
            (Loaded::Sweep(sweep), Some(name)) => match sweep.shards.into_iter().find(|s| &s.name == name) {
                Some(s) => s.study,
                None => {
                    return refuse(format!(
                        "study {name:?} of {} is no longer in that file (its scenes or catalogs changed)",
                        record.study
                    ));
                }
            },
            (Loaded::Study(_), Some(name)) => {
                return refuse(format!(
                    "records study {name:?} of a sweep, but {} no longer lists several scenes or catalogs",
                    record.study
                ));
            }
            (Loaded::Sweep(_), None) => {
                return refuse(format!(
                    "records a single study, but {} now lists several scenes or catalogs",
                    record.study
                ));
            }
        }
    };
    let plan = Plan::new(&study, registry, &record.profile, out)?;
    if plan.fingerprint != record.fingerprint {
        return refuse(format!(
            "the study changed since this folder was made (fingerprint {} recorded, {} now: study file, scene or catalog edited)",
            record.fingerprint, plan.fingerprint
        ));
    }
    Ok((study, plan))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
    use super::*;

    const CONFIG: &str =
        "[[configurations]]\nname = \"2x lidar-16 + radar\"\nsensors = { \"lidar-16\" = 2, \"radar-4d\" = 1 }\n";

    fn fixture(name: &str) -> String {
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures").join(name)).unwrap()
    }

    /// A folder with two scenes (`arterial`, `collector`) and two catalogs (`list`, `sale`).
    fn folder() -> tempfile::TempDir {
        let d = tempfile::tempdir().unwrap();
        let scene = fixture("intersection.toml");
        std::fs::write(d.path().join("arterial.toml"), &scene).unwrap();
        std::fs::write(d.path().join("collector.toml"), scene.replace("lanes_in = 3", "lanes_in = 2")).unwrap();
        std::fs::write(d.path().join("list.toml"), fixture("sensors.toml")).unwrap();
        std::fs::write(d.path().join("sale.toml"), fixture("sensors.toml")).unwrap();
        d
    }

    fn err(text: &str, dir: &Path) -> String {
        match parse(text, dir, "sweep.toml") {
            Ok(_) => panic!("accepted:\n{text}"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn scenes_times_catalogs_are_studies_named_by_their_files() {
        let d = folder();
        let text = format!(
            "scenes = [\"arterial.toml\", \"collector.toml\"]\ncatalogs = [\"list.toml\", \"sale.toml\"]\n{CONFIG}"
        );
        let Loaded::Sweep(s) = parse(&text, d.path(), "sweep.toml").unwrap() else { panic!("not a sweep") };
        let names: Vec<&str> = s.shards.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["arterial-list", "arterial-sale", "collector-list", "collector-sale"]);
        let c = &s.shards[2].study;
        assert_eq!(c.file.scene.as_deref(), Some(Path::new("collector.toml")));
        assert_eq!(c.file.catalog.as_deref(), Some(Path::new("list.toml")));
        assert_eq!(c.shard.as_deref(), Some("collector-list"));
        assert_ne!(s.shards[0].study.scene_hash, c.scene_hash, "the collector scene was loaded, not the default");
        assert_eq!(s.shards[0].study.scene_hash, s.shards[1].study.scene_hash);
        // One list only: named by that list's files; the other file is every study's.
        let text = format!("catalog = \"sale.toml\"\nscenes = [\"arterial.toml\", \"collector.toml\"]\n{CONFIG}");
        let Loaded::Sweep(s) = parse(&text, d.path(), "sweep.toml").unwrap() else { panic!("not a sweep") };
        assert_eq!(s.shards.iter().map(|s| s.name.as_str()).collect::<Vec<_>>(), ["arterial", "collector"]);
        assert!(s.shards.iter().all(|s| s.study.file.catalog.as_deref() == Some(Path::new("sale.toml"))));
        // Without lists: one study, as before.
        assert!(matches!(parse(CONFIG, d.path(), "study.toml").unwrap(), Loaded::Study(_)));
    }

    #[test]
    fn a_non_finite_patch_is_refused_in_a_sweep_as_in_a_study() {
        let d = folder();
        for text in [
            format!("catalogs = [\"a.toml\", \"b.toml\"]\n{CONFIG}[detector_patch]\nvelocity_weight = nan\n"),
            format!("{CONFIG}[train_schedule]\nlr_max = -inf\n"),
        ] {
            let Err(e) = parse(&text, d.path(), "s.toml") else { panic!("accepted: {text}") };
            let e = e.to_string();
            assert!(e.contains("s.toml") && e.contains("must be a finite number"), "{e}");
            assert!(e.contains("detector_patch.velocity_weight = NaN") || e.contains("train_schedule.lr_max = -inf"));
        }
    }

    #[test]
    fn a_sweep_file_that_cannot_name_its_studies_apart_is_refused() {
        let d = folder();
        let e = err(&format!("scene = \"arterial.toml\"\nscenes = [\"collector.toml\"]\n{CONFIG}"), d.path());
        assert!(e.contains("give `scene` or `scenes`, not both"), "{e}");
        let e = err(&format!("catalogs = []\n{CONFIG}"), d.path());
        assert!(e.contains("`catalogs` = []"), "{e}");
        let e = err(&format!("scenes = \"arterial.toml\"\n{CONFIG}"), d.path());
        assert!(e.contains("`scenes` must be a list of file paths"), "{e}");
        std::fs::create_dir(d.path().join("other")).unwrap();
        std::fs::write(d.path().join("other/arterial.toml"), fixture("intersection.toml")).unwrap();
        let e = err(&format!("scenes = [\"arterial.toml\", \"other/arterial.toml\"]\n{CONFIG}"), d.path());
        assert!(e.contains("share the name \"arterial\"") && e.contains("other/arterial.toml"), "{e}");
        let e = err(&format!("scenes = [\"missing.toml\"]\n{CONFIG}"), d.path());
        assert!(e.contains("study \"missing\"") && e.contains("missing.toml"), "{e}");
        // The single-study loader points at the sweep loader.
        let e = Study::parse(&format!("scenes = [\"arterial.toml\"]\n{CONFIG}"), d.path(), "s.toml").unwrap_err();
        assert!(e.to_string().contains("a sweep of studies"), "{e}");
    }

    /// `weathers` is an axis of its own: one study per named condition (times scenes and
    /// catalogs), each with its weather in its dataset settings and so its own hashes; a bad
    /// condition, one beside `[dataset.weather]`, or an empty table is refused by name.
    #[test]
    fn weathers_are_studies_named_by_their_conditions() {
        let d = folder();
        let text = format!(
            "scenes = [\"arterial.toml\", \"collector.toml\"]\n\
             weathers = {{ clear = {{}}, \"Dense fog\" = {{ fog_visibility_m = 60.0 }}, rain = {{ rain_mm_h = 25.0 }} }}\n{CONFIG}"
        );
        let Loaded::Sweep(s) = parse(&text, d.path(), "sweep.toml").unwrap() else { panic!("not a sweep") };
        let names: Vec<&str> = s.shards.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "arterial-dense_fog",
                "arterial-clear",
                "arterial-rain",
                "collector-dense_fog",
                "collector-clear",
                "collector-rain"
            ]
        );
        let w = |i: usize| s.shards[i].study.dataset.weather;
        assert_eq!(w(0).fog_visibility_m, Some(60.0));
        assert!(w(1).is_clear());
        assert_eq!(w(2).rain_mm_h, 25.0);
        assert_ne!(format!("{:?}", s.shards[0].study.dataset), format!("{:?}", s.shards[1].study.dataset));
        // Weathers alone make a sweep of the one scene and catalog.
        let text = format!("weathers = {{ fog = {{ fog_visibility_m = 100.0 }} }}\n{CONFIG}");
        let Loaded::Sweep(s) = parse(&text, d.path(), "sweep.toml").unwrap() else { panic!("not a sweep") };
        assert_eq!(s.shards.iter().map(|s| s.name.as_str()).collect::<Vec<_>>(), ["fog"]);
        let e = err(&format!("weathers = {{ fog = {{ fog_visibility_m = 0.5 }} }}\n{CONFIG}"), d.path());
        assert!(e.contains("weathers.fog") && e.contains("fog_visibility_m"), "{e}");
        let e = err(&format!("weathers = {{ fog = {{ visibility = 50.0 }} }}\n{CONFIG}"), d.path());
        assert!(e.contains("weathers.fog") && e.contains("visibility"), "{e}");
        let e = err(&format!("weathers = {{}}\n{CONFIG}"), d.path());
        assert!(e.contains("weathers = {}: name at least one"), "{e}");
        let e = err(&format!("weathers = {{ a = {{}} }}\n[dataset.weather]\nrain_mm_h = 5.0\n{CONFIG}"), d.path());
        assert!(e.contains("not both"), "{e}");
        let e = Study::parse(&format!("weathers = {{ a = {{}} }}\n{CONFIG}"), d.path(), "s.toml").unwrap_err();
        assert!(e.to_string().contains("a sweep of studies"), "{e}");
    }

    #[test]
    fn a_directory_of_studies_is_a_sweep_in_file_name_order() {
        let d = tempfile::tempdir().unwrap();
        let e = load(d.path()).unwrap_err().to_string();
        assert!(e.contains("holds no *.toml file"), "{e}");
        std::fs::write(d.path().join("b-site.toml"), CONFIG).unwrap();
        std::fs::write(d.path().join("a site.toml"), CONFIG).unwrap();
        std::fs::write(d.path().join("notes.txt"), "not a study").unwrap();
        let Loaded::Sweep(s) = load(d.path()).unwrap() else { panic!("not a sweep") };
        assert_eq!(s.shards.iter().map(|s| s.name.as_str()).collect::<Vec<_>>(), ["a_site", "b_site"]);
        assert!(s.shards.iter().all(|s| s.study.shard.is_none() && Path::new(&s.study.source).is_absolute()));
        std::fs::create_dir(d.path().join("scenes")).unwrap();
        std::fs::write(d.path().join("scenes/x.toml"), fixture("intersection.toml")).unwrap();
        std::fs::write(d.path().join("c.toml"), format!("scenes = [\"scenes/x.toml\"]\n{CONFIG}")).unwrap();
        let e = load(d.path()).unwrap_err().to_string();
        assert!(e.contains("c.toml") && e.contains("studies of one scene and catalog each"), "{e}");
    }
    /// The default study keeps the site in three training draws of four and gives every
    /// detector the footprint velocity head; `fixtures/turned-study.toml` is the same study (on
    /// the paper's sensors, `paper-sensors-study.toml`) with
    /// the presets' own head and augmentation: the same configurations, traffic and datasets, and
    /// a schedule equal to the preset's.
    #[test]
    fn the_turned_fixture_changes_the_heads_and_the_draws_only() {
        let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures");
        let Loaded::Study(v) = load(&fixtures.join("turned-study.toml")).unwrap() else { panic!("not a study") };
        let default = Study::load(&fixtures.join("paper-sensors-study.toml")).unwrap();
        assert_eq!(v.file.configurations, default.file.configurations);
        assert_eq!((&v.scene_hash, &v.catalog_hash), (&default.scene_hash, &default.catalog_hash));
        assert_eq!(format!("{:?}", v.dataset), format!("{:?}", default.dataset));
        let head = |s: &Study| {
            let patch = s.file.detector_patch.as_ref().unwrap();
            (patch["velocity_target"].as_str().map(str::to_owned), patch["velocity_weight"].as_f64())
        };
        assert_eq!(head(&default), (Some("footprint".to_owned()), Some(1.0)));
        assert_eq!(head(&v), (Some("positives".to_owned()), Some(0.2)));
        let preset = hilo_detector::train::TrainConfig::default();
        let kept = crate::plan::scheduled(&default, "centerpoint", &preset).unwrap().augmentation;
        let turned = crate::plan::scheduled(&v, "centerpoint", &preset).unwrap().augmentation;
        assert_eq!(format!("{turned:?}"), format!("{:?}", preset.augmentation));
        assert_eq!(
            (kept.keep_site_p, kept.rotate_deg, kept.flip_p),
            (0.75, preset.augmentation.rotate_deg, preset.augmentation.flip_p)
        );
    }

    /// The realism sweep (`fixtures/realism-study.toml`): the default study with the paper's
    /// catalog and the datasheet one, which differ in the LiDARs and the radars' effects.
    #[test]
    fn the_realism_fixture_sweeps_the_two_catalogs() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/realism-study.toml");
        let Loaded::Sweep(w) = load(&path).unwrap() else { panic!("not a sweep") };
        assert_eq!(w.shards.iter().map(|s| s.name.as_str()).collect::<Vec<_>>(), ["sensors", "sensors_datasheet"]);
        let (paper, sheet) = (&w.shards[0].study, &w.shards[1].study);
        assert_ne!(paper.catalog_hash, sheet.catalog_hash);
        assert_eq!(paper.file.configurations, sheet.file.configurations);
        for name in ["lidar-16", "lidar-32", "lidar-64"] {
            assert!(paper.catalog.lidar(name).unwrap().detection_range.is_none());
            assert!(sheet.catalog.lidar(name).unwrap().detection_range.is_some(), "{name}");
        }
        let (p, q) = (paper.catalog.radar("radar-4d").unwrap(), sheet.catalog.radar("radar-4d").unwrap());
        assert!(p.effects.is_ideal() && p.azimuth_table.is_empty());
        assert!(!q.effects.is_ideal() && !q.azimuth_table.is_empty());
        let ideal = hilo_sensor_models::RadarSpec { effects: Default::default(), azimuth_table: vec![], ..q.clone() };
        assert_eq!(*p, ideal, "the same radar otherwise");
    }

    /// `scripts/realism-ablation.py` writes a sweep of the default study: none, each effect
    /// alone, all; each shard differs from `ideal` by its effect and nothing else.
    #[test]
    fn the_realism_ablation_switches_one_effect_at_a_time() {
        use hilo_sensor_models::{RadarSpec, SensorSpec};
        let d = tempfile::tempdir().unwrap();
        let out = d.path().join("ablation");
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/realism-ablation.py");
        let run = std::process::Command::new("python3").arg(&script).arg(&out).output().unwrap();
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        let Loaded::Sweep(w) = load(&out).unwrap() else { panic!("not a sweep") };
        let names: Vec<&str> = w.shards.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names.len(), 17, "{names:?}");
        let get = |n: &str| &w.shards.iter().find(|s| s.name == n).unwrap().study;
        let ideal = get("ideal");
        let default =
            Study::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/paper-sensors-study.toml"))
                .unwrap();
        assert_eq!(ideal.catalog_hash, default.catalog_hash, "ideal is the paper's catalog");
        let sensors = |s: &Study| s.catalog.sensors().to_vec();
        // What each radar effect sets, and nothing else.
        let radar_effect = |n: &str, check: &dyn Fn(&RadarSpec) -> bool| {
            let s = get(n);
            assert_eq!(s.dataset.calibration_error, None, "{n}");
            for (a, b) in sensors(ideal).iter().zip(sensors(s)) {
                match (a, &b) {
                    (SensorSpec::Radar(a), SensorSpec::Radar(b)) => {
                        assert!(check(b), "{n}: {b:?}");
                        let back = RadarSpec {
                            effects: Default::default(),
                            azimuth_table: vec![],
                            azimuth_resolution_deg: a.azimuth_resolution_deg,
                            ..b.clone()
                        };
                        assert_eq!(*a, back, "{n}");
                    }
                    (a, b) => assert_eq!(a, b, "{n}"),
                }
            }
        };
        radar_effect("radar_azimuth", &|r| r.effects.is_ideal() && r.azimuth_table.len() == 3);
        radar_effect("radar_resolution", &|r| r.effects.doppler_resolution_mps.is_some() && r.azimuth_table.is_empty());
        radar_effect("radar_multipath", &|r| {
            r.effects.wall_multipath_loss_db.is_some() && r.effects.side_lobe_level_db.is_none()
        });
        radar_effect("radar_false_alarms", &|r| {
            r.effects.false_alarms_per_frame > 0.0 && r.effects.rcs_aspect_db == 0.0
        });
        radar_effect("radar_aspect", &|r| r.effects.rcs_aspect_db > 0.0 && r.effects.false_alarms_per_frame == 0.0);
        // LiDAR effects touch the LiDARs alone.
        let tables = get("lidar_tables");
        assert_eq!(tables.catalog.lidar("lidar-64").unwrap().elevations_deg.as_ref().map(Vec::len), Some(64));
        assert!(tables.catalog.lidar("lidar-64").unwrap().detection_range.is_none());
        assert!(get("lidar_range").catalog.lidar("lidar-16").unwrap().detection_range.is_some());
        assert_eq!(get("lidar_range").catalog.radar("radar-4d").unwrap(), ideal.catalog.radar("radar-4d").unwrap());
        // The beam's width needs the lidar equation: it comes on top of lidar_range, and only it.
        let (range, beam) = (get("lidar_range"), get("lidar_range_beam"));
        for n in ["lidar-16", "lidar-32", "lidar-64"] {
            let (a, b) = (range.catalog.lidar(n).unwrap(), beam.catalog.lidar(n).unwrap());
            assert!(a.beam.is_none() && b.beam.is_some(), "{n}");
            assert_eq!(*a, hilo_sensor_models::LidarSpec { beam: None, ..b.clone() }, "{n}");
        }
        // Rig settings on the paper's catalog; all of them together on the datasheet one.
        for n in ["calibration", "time_sync", "rolling_shutter", "vehicle_paint", "foliage"] {
            assert_eq!(get(n).catalog_hash, ideal.catalog_hash, "{n}");
        }
        assert!(get("calibration").dataset.calibration_error.is_some());
        assert_eq!(get("time_sync").dataset.time_sync_error_s, Some(0.005));
        assert!(get("rolling_shutter").dataset.rolling_shutter && !get("time_sync").dataset.rolling_shutter);
        let all = get("all");
        assert!(all.dataset.rolling_shutter && all.dataset.time_sync_error_s.is_some());
        assert_eq!(all.dataset.vehicle_paint, hilo_dataset::paint::VehiclePaint::Fleet);
        assert!(all.dataset.foliage.is_some() && get("foliage").dataset.foliage.is_some());
        assert!(get("vehicle_paint").dataset.foliage.is_none());
        assert!(!all.catalog.radar("radar-4d").unwrap().effects.is_ideal());
        assert!(all.catalog.lidar("lidar-16").unwrap().detection_range.is_some());
        assert!(all.catalog.lidar("lidar-16").unwrap().beam.is_some());
        // The width is cast at any profile where the study asks for it, and only there.
        assert_eq!((all.dataset.lidar_beam_width, beam.dataset.lidar_beam_width), (Some(true), Some(true)));
        assert!(
            w.shards.iter().filter(|s| !["all", "lidar_range_beam"].contains(&s.name.as_str())).all(|s| s
                .study
                .dataset
                .lidar_beam_width
                .is_none())
        );
        // It refuses a folder that holds something.
        let again = std::process::Command::new("python3").arg(&script).arg(&out).output().unwrap();
        assert!(!again.status.success());
    }

    /// `extends` lays a file over another study: tables merge field by field, lists and
    /// `[[configurations]]` replace, `scenes` replaces the base's `scene`; a chain of two, a
    /// base that is not there and a value that is not a path are refused by name.
    #[test]
    fn a_study_extends_another() {
        let d = tempfile::tempdir().unwrap();
        std::fs::write(d.path().join("scene.toml"), include_str!("../../../fixtures/intersection.toml")).unwrap();
        std::fs::write(d.path().join("other.toml"), include_str!("../../../fixtures/intersection.toml")).unwrap();
        std::fs::write(d.path().join("base.toml"), format!("scene = \"scene.toml\"\n{CONFIG}")).unwrap();
        let child = d.path().join("child.toml");
        let write = |text: &str| std::fs::write(&child, text).unwrap();
        write("extends = \"base.toml\"\n[dataset]\nscenes = 3\n");
        let Loaded::Study(s) = load(&child).unwrap() else { panic!("not a study") };
        let base = Study::load(&d.path().join("base.toml")).unwrap();
        assert_eq!(s.file.dataset.scenes, 3);
        assert_eq!(s.file.dataset.seconds, base.file.dataset.seconds, "[dataset] merges field by field");
        assert_eq!(s.file.configurations, base.file.configurations);
        write("extends = \"base.toml\"\nscenes = [\"scene.toml\", \"other.toml\"]\n");
        let Loaded::Sweep(w) = load(&child).unwrap() else { panic!("not a sweep") };
        assert_eq!(w.shards.iter().map(|s| s.name.as_str()).collect::<Vec<_>>(), ["scene", "other"]);
        write("extends = \"base.toml\"\n[[configurations]]\nname = \"one\"\nsensors = { \"lidar-16\" = 1 }\n");
        let Loaded::Study(s) = load(&child).unwrap() else { panic!("not a study") };
        assert_eq!(s.file.configurations.len(), 1, "[[configurations]] replaces");
        std::fs::write(d.path().join("middle.toml"), "extends = \"base.toml\"\n").unwrap();
        for (text, needle) in [
            ("extends = \"middle.toml\"\n", "extends another in turn"),
            ("extends = \"missing.toml\"\n", "missing.toml"),
            ("extends = 3\n", "extends = 3"),
        ] {
            write(text);
            let e = load(&child).err().map(|e| e.to_string()).unwrap_or_default();
            assert!(e.contains(needle), "{text:?}: {e}");
        }
    }
}
