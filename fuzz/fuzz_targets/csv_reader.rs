//! Bytes -> `CsvTable::from_reader` (the parser behind `CsvTable::read`),
//! then `Record::from_table` with column choices taken from the table.
#![no_main]
use gb_core::{CsvTable, Record};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(table) = CsvTable::from_reader(data, "fuzz.csv".into()) else {
        return;
    };
    let _ = table.n_rows();
    for n in &table.names {
        let _ = table.column(n);
    }
    let _ = table.column("no-such-column");
    // Automatic choice: every column but the output-like one are inputs.
    let _ = Record::from_table(&table, &[], None);
    let names = &table.names;
    if let Some(last) = names.last() {
        let inputs: Vec<String> = names[..names.len() - 1].to_vec();
        let _ = Record::from_table(&table, &inputs, Some(last));
        let _ = Record::from_table(&table, &[], Some(last));
        // Output also among the inputs, and an unknown column.
        let _ = Record::from_table(&table, names, Some(last));
        let _ = Record::from_table(&table, &["nope".to_string()], Some(last));
    }
    if let Some(first) = names.first() {
        let _ = Record::from_table(&table, &[first.clone()], None);
    }
});
