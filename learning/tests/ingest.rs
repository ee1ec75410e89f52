use polars::prelude::*;
use std::sync::mpsc::sync_channel;

#[test]
fn exp() {
    let dir = std::env::temp_dir().join("exp_polars");
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("a.csv");
    std::fs::write(&p, "\u{feff}t , signal,value\n0,C4,1\n\n  \n0, \"C5\" ,0\n,,\n10,C4,true\n5,C9\n").unwrap();
    let schema: Schema = ["c0", "c1", "c2"].iter().map(|n| Field::new((*n).into(), DataType::String)).collect();
    let lf = LazyCsvReader::new(PlRefPath::try_from_path(&p).unwrap())
        .with_has_header(true)
        .with_schema(Some(Arc::new(schema)))
        .with_glob(false)
        .with_missing_is_null(true)
        .finish()
        .unwrap();
    let (tx, rx) = sync_channel::<DataFrame>(1);
    let lf = lf.sink_batches(PlanCallback::new(move |df| Ok(tx.send(df).is_err())), true, std::num::NonZeroUsize::new(2)).unwrap();
    let h = std::thread::spawn(move || lf.collect_with_engine(Engine::Streaming).map(|_| ()));
    for df in rx { for i in 0..df.height() { let r: Vec<_> = df.columns().iter().map(|c| c.str().unwrap().get(i).map(|s| s.to_string())).collect(); println!("{r:?}"); } }
    println!("{:?}", h.join().unwrap());
}
