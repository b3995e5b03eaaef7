use gateway::config;

#[test]
fn demo_round_trip_probe() {
    let c = config::demo();
    let text = toml::to_string(&c).expect("serialize");
    println!("{text}");
    let back = config::parse(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
    assert_eq!(back, c);
}
