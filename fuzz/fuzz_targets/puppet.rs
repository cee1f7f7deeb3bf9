#![no_main]
//! `likeness_fuzzing::puppet` under libFuzzer, with the crate's structure-aware edits mixed
//! into libFuzzer's own mutations.

use libfuzzer_sys::{fuzz_mutator, fuzz_target, fuzzer_mutate};
use likeness_fuzzing::Target;
use likeness_fuzzing::mutate::libfuzzer_mutate;

fuzz_target!(|data: &[u8]| likeness_fuzzing::puppet(data));

fuzz_mutator!(|data: &mut [u8], size: usize, max_size: usize, seed: u32| {
    libfuzzer_mutate(
        Target::Puppet.format(),
        data,
        size,
        max_size,
        seed,
        fuzzer_mutate,
    )
});
