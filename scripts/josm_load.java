// Load OSM files with JOSM's own reader (what JOSM's File > Open runs) and print what it read:
// nodes, ways, lanelet relations, relations with missing members, ways with missing nodes.
//
//     apt-get install josm    # Debian's JOSM; then, with Java 11 or later:
//     java -cp /usr/share/josm/josm.jar scripts/josm_load.java out/*.osm
//
// docs/maps.md gives what it printed for `smlworld map convert`'s OpenDRIVE conversions.
import java.io.FileInputStream;
import org.openstreetmap.josm.data.osm.DataSet;
import org.openstreetmap.josm.data.osm.Relation;
import org.openstreetmap.josm.data.osm.Way;
import org.openstreetmap.josm.data.Preferences;
import org.openstreetmap.josm.spi.preferences.Config;
import org.openstreetmap.josm.gui.progress.NullProgressMonitor;
import org.openstreetmap.josm.io.OsmReader;

public class josm_load {
    public static void main(String[] args) throws Exception {
        Config.setPreferencesInstance(new Preferences());
        for (String f : args) {
            DataSet ds = OsmReader.parseDataSet(new FileInputStream(f), NullProgressMonitor.INSTANCE);
            long lanelets = ds.getRelations().stream().filter(r -> "lanelet".equals(r.get("type"))).count();
            long incomplete = ds.getRelations().stream().filter(Relation::hasIncompleteMembers).count();
            long badWays = ds.getWays().stream().filter(w -> w.getNodesCount() < 2 || w.hasIncompleteNodes()).count();
            System.out.println(f + ": nodes " + ds.getNodes().size() + ", ways " + ds.getWays().size() + ", relations " + ds.getRelations().size() + ", lanelets " + lanelets + ", incomplete relations " + incomplete + ", broken ways " + badWays);
        }
    }
}
