use super::*;
use crate::protocols::{CoilAreas, InputAreas};

fn slave(write_enable: Vec<AddressRange>) -> ModbusSlaveRtuConfig {
    ModbusSlaveRtuConfig {
        address: 222,
        operating_mode: crate::protocols::OperatingMode::Normal,
        delay_multiplier: 1,
        unit_id: Some(50),
        coils: CoilAreas::default(),
        discrete_inputs: InputAreas::default(),
        holding_db: 800,
        input_db: 800,
        write_enable,
    }
}

fn range(table: ModbusTable, start: u16, count: u32) -> AddressRange {
    AddressRange {
        table,
        start,
        count,
    }
}

fn convert(write_enable: Vec<AddressRange>) -> Result<AddressMap, Vec<ConvertIssue>> {
    let cfg = slave(write_enable);
    address_map(&cfg, &memory_layout([&cfg], None))
}

fn keys(issues: &[ConvertIssue]) -> Vec<&str> {
    issues.iter().map(|i| i.key.as_str()).collect()
}

#[test]
fn the_default_config_is_the_manuals_example() {
    let cfg = slave(vec![
        range(ModbusTable::Coil, 0, 1024),
        range(ModbusTable::Holding, 0, 512),
    ]);
    let layout = memory_layout([&cfg], None);
    assert_eq!(
        (
            layout.m_bytes,
            layout.q_bytes,
            layout.i_bytes,
            layout.timers,
            layout.counters
        ),
        // M 1000 + 128 bytes, Q and I 100 + 128, T 100 + 126, C 200 + 3.
        (1128, 228, 228, 226, 203)
    );
    assert_eq!(layout.data_blocks, vec![(800, 512)]);
    let params = slave_params(&cfg, &layout).expect("converts");
    assert_eq!(params.address(), 222);
    let example = AddressMap::manual_example();
    let map = params.map();
    assert_eq!(map.coils(), example.coils());
    assert_eq!(map.inputs(), example.inputs());
    assert_eq!(
        *map.limits(),
        WriteLimits {
            memory: Some((1000, 1127)),
            outputs: None,
            data_blocks: Some((800, 800)),
        }
    );
    assert!(check(&cfg).is_empty());
}

#[test]
fn write_enables_convert_to_whole_bytes_and_dbs() {
    // Coils 8..23 are M 1001..1002; 1024..2047 all of Q 100..227; registers 0..1023 DB 800..801.
    let map = convert(vec![
        range(ModbusTable::Coil, 8, 16),
        range(ModbusTable::Coil, 1024, 1024),
        range(ModbusTable::Holding, 0, 512),
        range(ModbusTable::Holding, 512, 512),
    ])
    .expect("converts");
    assert_eq!(
        *map.limits(),
        WriteLimits {
            memory: Some((1001, 1002)),
            outputs: Some((100, 227)),
            data_blocks: Some((800, 801)),
        }
    );
    // One range across the M and Q rows enables a part of each.
    let map = convert(vec![range(ModbusTable::Coil, 1016, 16)]).expect("converts");
    assert_eq!(map.limits().memory, Some((1127, 1127)));
    assert_eq!(map.limits().outputs, Some((100, 100)));
}

#[test]
fn what_the_limits_cannot_express_is_refused() {
    let refused = |ranges: Vec<AddressRange>| convert(ranges).expect_err("refused");
    // Inside a byte.
    let issues = refused(vec![range(ModbusTable::Coil, 3, 8)]);
    assert_eq!(keys(&issues), ["write_enable[0]"]);
    assert!(issues[0].message.contains("whole bytes"), "{issues:?}");
    // Two separate ranges in M.
    let issues = refused(vec![
        range(ModbusTable::Coil, 0, 8),
        range(ModbusTable::Coil, 16, 8),
    ]);
    assert!(issues[0].message.contains("one byte range"), "{issues:?}");
    // Timers.
    let issues = refused(vec![range(ModbusTable::Coil, 2048, 16)]);
    assert!(issues[0].message.contains("read-only"), "{issues:?}");
    // Part of a DB, and two DBs apart.
    let issues = refused(vec![
        range(ModbusTable::Holding, 0, 100),
        range(ModbusTable::Holding, 600, 10),
    ]);
    assert_eq!(keys(&issues), ["write_enable[0]", "write_enable[1]"]);
    assert!(issues[0].message.contains("part of DB 800"), "{issues:?}");
    assert!(issues[1].message.contains("part of DB 801"), "{issues:?}");
    let issues = refused(vec![
        range(ModbusTable::Holding, 0, 512),
        range(ModbusTable::Holding, 1024, 512),
    ]);
    assert_eq!(keys(&issues), ["write_enable[1]"]);
    // An input table cannot be written.
    let issues = refused(vec![range(ModbusTable::Input, 0, 1)]);
    assert_eq!(keys(&issues), ["write_enable[0]"]);
}

#[test]
fn a_db_of_configured_length_is_enabled_whole_by_its_length() {
    let cfg = slave(vec![range(ModbusTable::Holding, 0, 100)]);
    let layout = memory_layout([&cfg], Some(&[(800, 100)]));
    let map = address_map(&cfg, &layout).expect("the whole DB 800");
    assert_eq!(map.limits().data_blocks, Some((800, 800)));
}

#[test]
fn an_area_switched_off_is_not_mapped() {
    let mut cfg = slave(Vec::new());
    cfg.coils.counters.count = 0;
    cfg.discrete_inputs.inputs.count = 0;
    let layout = memory_layout([&cfg], None);
    assert_eq!((layout.counters, layout.i_bytes), (0, 0));
    let map = address_map(&cfg, &layout).expect("converts");
    assert_eq!(map.coils().len(), 3);
    assert_eq!(map.inputs().len(), 1);
}
