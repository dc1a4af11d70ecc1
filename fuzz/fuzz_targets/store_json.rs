//! Tileset manifests (`tileset.json`) and index chunks as the store and the server read them
//! (`serde_json::from_slice` into `Manifest` / `IndexChunk`): an `Ok` value must
//! survive the store's own writing (pretty JSON) and reading back unchanged.
#![no_main]
use libfuzzer_sys::fuzz_target;
use terrastream::store::{IndexChunk, Manifest};

fn roundtrip<T>(data: &[u8])
where
    T: serde::Serialize + serde::de::DeserializeOwned + PartialEq + std::fmt::Debug,
{
    let Ok(v) = serde_json::from_slice::<T>(data) else { return };
    let text =
        serde_json::to_vec_pretty(&v).unwrap_or_else(|e| panic!("parsed value does not serialise: {e}"));
    let back: T = serde_json::from_slice(&text).unwrap_or_else(|e| {
        panic!("re-serialised value does not parse: {e}\n{}", String::from_utf8_lossy(&text))
    });
    assert_eq!(v, back, "value changed through JSON");
}

fuzz_target!(|data: &[u8]| {
    roundtrip::<Manifest>(data);
    roundtrip::<IndexChunk>(data);
});
