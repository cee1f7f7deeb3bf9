#![no_main]
//! Any bytes: the loader returns a puppet or an error, never panics.

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(puppet) = retarget::Puppet::from_slice(data, std::path::Path::new("fuzz.glb"), None) {
        let r = retarget::Retargeter::new(&puppet, &retarget::MappingData::default());
        let _ = r.pose(&[0.5; face_channels::N], Some([10.0, 5.0, -3.0]));
    }
});

mod face_channels {
    pub const N: usize = 52;
}
