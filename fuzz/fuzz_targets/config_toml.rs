//! The server's TOML configuration file: any text through what `PartialConfig::from_toml_file`
//! does with the file's text (`toml::from_str`), then `resolve`. An `Ok` configuration must
//! have usable limits and source names that stay inside the store directory.
#![no_main]
use libfuzzer_sys::fuzz_target;
use terrastream::server::{PartialConfig, valid_name};

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let Ok(partial) = toml::from_str::<PartialConfig>(text) else { return };
    let Ok(c) = partial.resolve() else { return };
    assert!(c.max_connections >= 1 && c.max_in_flight >= 1 && c.bake_workers >= 1, "{c:?}");
    assert!(c.request_timeout.as_secs() >= 1, "{c:?}");
    assert!(c.poll.as_millis() >= 50, "{c:?}");
    assert!(c.gpu_budget_mib >= 1, "{c:?}");
    for t in [&c.admin_token, &c.read_token].into_iter().flatten() {
        assert!(t.len() >= 8 && t.bytes().all(|b| b.is_ascii_graphic()), "token {t:?}");
    }
    let mut names: Vec<&str> = c.sources.iter().map(|s| s.name.as_str()).collect();
    for n in &names {
        // `open_source` bakes into `store/NAME`: any other name could leave the store.
        assert!(valid_name(n), "source name {n:?} is not a valid tileset name");
    }
    names.sort_unstable();
    let before = names.len();
    names.dedup();
    assert_eq!(before, names.len(), "duplicate source names");
});
