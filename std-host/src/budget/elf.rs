//! The firmware ELF's section sizes, read from its section headers with the `object` crate.

use anyhow::{ensure, Context, Result};
use object::elf::FileHeader32;
use object::read::elf::{FileHeader, SectionHeader};
use object::LittleEndian;

/// `(name, size)` of every section of a 32-bit little-endian ELF, from its section headers
/// (the null section left out).
pub fn elf_sections(elf: &[u8]) -> Result<Vec<(String, u64)>> {
    ensure!(elf.get(..4) == Some(b"\x7fELF".as_slice()), "not an ELF file");
    ensure!(
        elf.get(4) == Some(&1) && elf.get(5) == Some(&1),
        "not a 32-bit little-endian ELF"
    );
    let header = FileHeader32::<LittleEndian>::parse(elf).context("malformed ELF header")?;
    let endian = header.endian().context("malformed ELF header")?;
    let sections = header.sections(endian, elf).context("truncated ELF")?;
    sections
        .iter()
        .skip(1)
        .map(|section| {
            let name = sections
                .section_name(endian, section)
                .context("section name outside the file")?;
            Ok((
                String::from_utf8_lossy(name).into_owned(),
                section.sh_size(endian).into(),
            ))
        })
        .collect()
}
