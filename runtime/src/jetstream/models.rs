//! Models through the store: `gardefou learn … --publish URL` puts a plant's
//! model version in the JetStream object store [`BUCKET`], under the plant's
//! name; fleet workers started without `--plant` serve every plant there,
//! and monitors with `--follow-models` take each new version of theirs.
//!
//! An object holds one [`Bundle`]: the plant file's text and the model's,
//! with the model's version ([`model_version`]). Both go together, so that a
//! reader never sees a model beside another plant file. The object's
//! `version` metadata repeats the version, for the NATS tools.
//!
//! A reader takes a new version at a safe point, between two messages: the
//! diagnosers start again from the signal values read, every clock unknown,
//! as after a reconnection. A version whose plant file does not fit the one
//! served (another number of signals) is refused, with a warning, and the
//! old version stays.

use std::path::Path;

use async_nats::jetstream::{self, object_store};
use diagnoser::model::Model;
use diagnoser::{Failure, Plant};

use super::connect;
use futures_util::StreamExt;
use serde::{Deserialize, Serialize};
use tokio::io::AsyncReadExt;

/// The object store of the plants' models.
pub const BUCKET: &str = "gardefou-models";
/// Largest bundle read: a model is tens of kilobytes; more is not one.
const MAX_BUNDLE: usize = 64 << 20;

/// One model version of a plant, as the store keeps it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Bundle {
    /// [`model_version`] of `model`.
    pub version: String,
    /// The plant file's text.
    pub plant: String,
    /// The `model.json` text.
    pub model: String,
}

/// A plant's model version, read and checked.
#[derive(Debug, Clone)]
pub struct Version {
    /// The plant's name in the subjects (the object's name).
    pub name: String,
    /// Its plant file.
    pub plant: Plant,
    /// Its model.
    pub model: Model,
    /// The model's version.
    pub version: String,
}

/// A model's version: the first 12 hexadecimal digits of the SHA-256 of
/// its `model.json`, so that the same model has the same version wherever
/// it is read from.
pub fn model_version(model_json: &[u8]) -> String {
    let digest = ring::digest::digest(&ring::digest::SHA256, model_json);
    digest.as_ref()[..6]
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

impl Bundle {
    /// The bundle of a plant file's text and a model's.
    pub fn new(plant: String, model: String) -> Bundle {
        Bundle {
            version: model_version(model.as_bytes()),
            plant,
            model,
        }
    }

    /// Reads the bundle stored under `name`, checking both files; errors
    /// name the object and the file.
    pub fn read(name: &str, bytes: &[u8]) -> Result<Version, String> {
        let at = format!("nats object store {BUCKET}, object {name}");
        let b: Bundle =
            serde_json::from_slice(bytes).map_err(|e| format!("{at}: not a model bundle ({e})"))?;
        let plant = Plant::parse(&b.plant, Path::new(&format!("{at}: plant.toml")))
            .map_err(|e| e.to_string())?;
        let model = Model::parse(&b.model, Path::new(&format!("{at}: model.json")))
            .map_err(|e| e.to_string())?;
        let version = model_version(b.model.as_bytes());
        if version != b.version {
            return Err(format!(
                "{at}: version {} does not match its model ({version})",
                b.version
            ));
        }
        Ok(Version {
            name: name.to_string(),
            plant,
            model,
            version,
        })
    }
}

impl Version {
    /// Whether `next` may replace this version between two messages: the
    /// same signals in the same order, since the values read carry over by
    /// position. Why not, if not.
    pub fn takes_over(&self, next: &Version) -> Result<(), String> {
        let names = |v: &Version| -> Vec<String> {
            v.plant
                .signals
                .iter()
                .map(|(_, s)| s.name.clone())
                .collect()
        };
        if names(self) == names(next) {
            Ok(())
        } else {
            Err(format!(
                "model {} of plant {}: its plant file's signals differ from those of model {}; the values read cannot carry over",
                next.version, next.name, self.version
            ))
        }
    }
}

/// The store, made if missing.
pub async fn store(js: &jetstream::Context) -> Result<object_store::ObjectStore, String> {
    match js.get_object_store(BUCKET).await {
        Ok(s) => Ok(s),
        Err(_) => js
            .create_object_store(object_store::Config {
                bucket: BUCKET.to_string(),
                description: Some("gardefou: one model version per plant".into()),
                storage: jetstream::stream::StorageType::File,
                ..object_store::Config::default()
            })
            .await
            .map_err(|e| format!("object store {BUCKET}: {e}")),
    }
}

/// Stores `bundle` as plant `name`'s model version.
pub async fn put(
    store: &object_store::ObjectStore,
    name: &str,
    bundle: &Bundle,
) -> Result<(), String> {
    let bytes = serde_json::to_vec(bundle).map_err(|e| e.to_string())?;
    let meta = object_store::ObjectMetadata {
        name: name.to_string(),
        description: Some(format!("gardefou model {} of plant {name}", bundle.version)),
        metadata: [("version".to_string(), bundle.version.clone())].into(),
        ..object_store::ObjectMetadata::default()
    };
    store
        .put(meta, &mut bytes.as_slice())
        .await
        .map(|_| ())
        .map_err(|e| format!("object store {BUCKET}, object {name}: {e}"))
}

/// Reads plant `name`'s model version; `None` when there is none.
pub async fn get(store: &object_store::ObjectStore, name: &str) -> Result<Option<Version>, String> {
    let mut object = match store.get(name).await {
        Ok(o) => o,
        Err(e) if e.kind() == object_store::GetErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(format!("object store {BUCKET}, object {name}: {e}")),
    };
    if object.info().size > MAX_BUNDLE {
        return Err(format!(
            "object store {BUCKET}, object {name}: {} bytes, more than a model bundle may hold ({MAX_BUNDLE})",
            object.info().size
        ));
    }
    let mut bytes = Vec::with_capacity(object.info().size);
    object
        .read_to_end(&mut bytes)
        .await
        .map_err(|e| format!("object store {BUCKET}, object {name}: {e}"))?;
    Bundle::read(name, &bytes).map(Some)
}

/// A change in the store: a plant's new version, or its removal.
#[derive(Debug)]
pub enum Change {
    /// A version was stored (or was there when watching began): the
    /// plant's name, and the version its metadata names (read before the
    /// object, so that a version already held is not read again).
    Stored(String, Option<String>),
    /// The plant's model was removed.
    Removed(String),
}

/// Follows the store: first what it holds, then every change, as the
/// names of the plants that changed.
pub async fn watch(
    store: &object_store::ObjectStore,
) -> Result<impl futures_util::Stream<Item = Result<Change, String>> + use<>, String> {
    let watch = store
        .watch_with_history()
        .await
        .map_err(|e| format!("object store {BUCKET}: {e}"))?;
    Ok(watch.map(|info| {
        let info = info.map_err(|e| format!("object store {BUCKET}: {e}"))?;
        Ok(if info.deleted {
            Change::Removed(info.name)
        } else {
            let version = info.metadata.get("version").cloned();
            Change::Stored(info.name, version)
        })
    }))
}

/// `gardefou learn --publish`: stores `bundle` as plant `name`'s model
/// version on the server at `url`.
pub fn publish(url: &str, name: &str, bundle: &Bundle) -> Result<(), Failure> {
    super::record::Subjects::of(name).map_err(|e| Failure::bad(format!("--nats-plant: {e}")))?;
    with_store(url, async |store| {
        put(&store, name, bundle)
            .await
            .map_err(|e| Failure::Io(format!("nats {url}: {e}")))
    })
}

/// `gardefou monitor --follow-models` without `--model`: plant `name`'s
/// version in the store at `url` now.
pub fn fetch(url: &str, name: &str) -> Result<Version, Failure> {
    with_store(url, async |store| match get(&store, name).await {
        Ok(Some(v)) => Ok(v),
        Ok(None) => Err(Failure::bad(format!(
            "nats {url}: object store {BUCKET} has no model of plant {name} (publish one with `gardefou learn … --publish {url}`)"
        ))),
        Err(e) => Err(Failure::bad(e)),
    })
}

/// Runs `f` on the store at `url`, in a runtime of its own (for the verbs
/// that are not async).
fn with_store<T>(
    url: &str,
    f: impl AsyncFnOnce(object_store::ObjectStore) -> Result<T, Failure>,
) -> Result<T, Failure> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| Failure::Io(format!("cannot start the runtime: {e}")))?;
    runtime.block_on(async {
        let js = connect(url).await?;
        let store = store(&js)
            .await
            .map_err(|e| Failure::Io(format!("nats {url}: {e}")))?;
        f(store).await
    })
}

/// How long a monitor following the store waits before trying the broker
/// again.
const FOLLOW_RETRY: std::time::Duration = std::time::Duration::from_secs(1);

/// `monitor --follow-models`: every version of plant `name` stored at `url`
/// from now on (and the one there now, unless it is `version`, the one the
/// monitor starts with), read and checked, on a channel. The
/// task keeps trying while the broker is away: the monitor goes on with
/// the version it has.
pub fn follow(url: String, name: String, version: String) -> tokio::sync::mpsc::Receiver<Version> {
    let (tx, rx) = tokio::sync::mpsc::channel(4);
    tokio::spawn(async move {
        let mut last = version;
        while !tx.is_closed() {
            if let Err(e) = follow_once(&url, &name, &tx, &mut last).await {
                eprintln!("warning: nats {url}: {e}; new models are not followed until it answers");
            }
            tokio::time::sleep(FOLLOW_RETRY).await;
        }
    });
    rx
}

async fn follow_once(
    url: &str,
    name: &str,
    tx: &tokio::sync::mpsc::Sender<Version>,
    last: &mut String,
) -> Result<(), String> {
    let js = connect(url).await.map_err(|e| match e {
        Failure::BadInput(m) | Failure::Io(m) => m,
        Failure::Closed => "closed".into(),
    })?;
    let store = store(&js).await?;
    let mut changes = Box::pin(watch(&store).await?);
    while let Some(change) = changes.next().await {
        match change? {
            Change::Stored(n, version) if n == name && version.as_ref() != Some(last) => {
                match get(&store, name).await {
                    Ok(Some(v)) => {
                        last.clone_from(&v.version);
                        if tx.send(v).await.is_err() {
                            return Ok(());
                        }
                    }
                    Ok(None) => {}
                    Err(e) => eprintln!("warning: {e}; this version is not taken"),
                }
            }
            _ => {}
        }
    }
    Err(format!("object store {BUCKET}: the watch ended"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn files() -> (String, String) {
        let plant = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../datasets/data/sorting/F2/plant.toml"
        ));
        let model = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../diagnoser/tests/fixtures/diagnosis/sorting-model.json"
        ));
        (plant.expect("plant"), model.expect("model"))
    }

    #[test]
    fn a_bundle_reads_back_with_its_version() {
        let (plant, model) = files();
        let b = Bundle::new(plant, model.clone());
        let bytes = serde_json::to_vec(&b).expect("bytes");
        let v = Bundle::read("line1", &bytes).expect("read");
        assert_eq!(v.version, model_version(model.as_bytes()));
        assert_eq!(v.name, "line1");
        assert!(!v.plant.parts.is_empty());
    }

    #[test]
    fn a_bundle_whose_version_lies_or_whose_files_are_bad_is_refused() {
        let (plant, model) = files();
        let mut b = Bundle::new(plant.clone(), model.clone());
        b.version = "000000000000".into();
        let e = Bundle::read("line1", &serde_json::to_vec(&b).expect("bytes")).unwrap_err();
        assert!(e.contains("does not match"), "{e}");
        let b = Bundle::new(plant.replace("[[parts]]", "[[parts]\n"), model.clone());
        let e = Bundle::read("line1", &serde_json::to_vec(&b).expect("bytes")).unwrap_err();
        assert!(e.contains("object line1: plant.toml"), "{e}");
        let b = Bundle::new(plant, "{\"version\": 1}".into());
        let e = Bundle::read("line1", &serde_json::to_vec(&b).expect("bytes")).unwrap_err();
        assert!(e.contains("model.json"), "{e}");
        let e = Bundle::read("line1", b"not json").unwrap_err();
        assert!(e.contains("not a model bundle"), "{e}");
    }

    #[test]
    fn a_version_with_other_signals_cannot_take_over() {
        let (plant, model) = files();
        let read = |plant: &str| {
            let b = Bundle::new(plant.to_string(), model.clone());
            Bundle::read("line1", &serde_json::to_vec(&b).expect("bytes")).expect("read")
        };
        let (old, same) = (read(&plant), read(&plant));
        assert!(old.takes_over(&same).is_ok());
        let renamed = read(&plant.replace("C5", "C55"));
        let e = old.takes_over(&renamed).unwrap_err();
        assert!(e.contains("signals differ"), "{e}");
    }
}
